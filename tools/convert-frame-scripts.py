#!/usr/bin/env python3
"""Converts frame files of the formats used before the frame script
(conformance/check/README.md) into frame scripts of version 2, in place.

A frame script of version 1 (`mbconform-script 1`) is version 2 without
cases, flags and readings: its header is rewritten and every line kept. Its
plan comments (`# ID  [LEVEL] CLAUSE`, `# (skip: REASON)`, written by
`run --plan` of version 1) become `case` blocks.

    tools/convert-frame-scripts.py [--mbconform build/bin/mbconform] FILE...

Old property regressions (conformance/properties/regressions/*.txt: `device`,
`fault`, hex RTU frames, `advance US`, `power-cycle`) and old fuzz reproducers
(`pdu UNIT HEX`, `probe UNIT HEX`, `raw HEX`, `raw@N HEX`, `advance US`).
A frame with a right CRC becomes `rtu` (a unit and a PDU, replayable on any
target), a corrupted one `raw-rtu`. With --mbconform, each regression is then
replayed through the property model (`mbconform props --replay FILE --out DIR`
on the clean reference device) and written back with the expectations the
model, written from the spec, gives each step. Files already in the new
format are left alone.
"""
import argparse
import os
import shutil
import subprocess
import sys
import tempfile

HEADER = "mbconform-script 2"
HEADER_V1 = "mbconform-script 1"


def crc16(data):
    c = 0xFFFF
    for x in data:
        c ^= x
        for _ in range(8):
            c = (c >> 1) ^ 0xA001 if c & 1 else c >> 1
    return c


def hexs(data):
    return " ".join("%02X" % b for b in data)


def frame_line(adu, gap=None):
    if gap is None and len(adu) >= 4 and crc16(adu[:-2]) == adu[-2] | adu[-1] << 8:
        return "rtu " + hexs(adu)
    words = ["%02X" % b for b in adu]
    if gap is not None:
        words.insert(gap, "|")
    return "raw-rtu " + " ".join(words)


def with_crc(unit, pdu):
    c = crc16(bytes([unit]) + pdu)
    return bytes([unit]) + pdu + bytes([c & 0xFF, c >> 8])


def convert(text):
    out = [HEADER]
    for line in text.splitlines():
        body, hash_, note = line.partition("#")
        body = body.strip()
        note = note.strip()
        if not body:
            out.append(line.rstrip() if hash_ else "")
            continue
        w = body.split()
        if w[0] in ("device", "fault", "power-cycle") or w[0] == "advance":
            step = body
        elif w[0] in ("pdu", "probe"):  # old fuzz reproducer: a PDU for a unit
            step = frame_line(with_crc(int(w[1]), bytes.fromhex("".join(w[2:]))))
            step += "  -> normal" if w[0] == "probe" else "  -> any-or-silence"
        elif w[0] == "raw" or w[0].startswith("raw@"):
            gap = int(w[0][4:]) if w[0].startswith("raw@") else None
            step = frame_line(bytes.fromhex("".join(w[1:])), gap)
        else:  # old regression: a whole RTU frame as hex
            step = frame_line(bytes.fromhex("".join(w)))
        out.append(step + ("   # " + note if note else ""))
    while out and out[-1] == "":
        out.pop()
    return "\n".join(out) + "\n"


def from_v1(text):
    """A version 1 script as version 2: the header, and a v1 plan's case
    comments as `case` blocks (a skipped case's steps stay commented out)."""
    import re
    out = [HEADER]
    case_comment = re.compile(r"^# (\S+)  \[(MUST|SHOULD|OBSERVED)\] (.*)$")
    for line in text.splitlines()[1:]:
        m = case_comment.match(line)
        if m:
            out.append("case %s %s %s" % m.groups())
            continue
        if line.startswith("# (skip: ") and line.endswith(")"):
            out.append("skip " + line[len("# (skip: "):-1])
            continue
        out.append(line)
    return "\n".join(out) + "\n"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mbconform", help="the mbconform binary: add the property model's expectations")
    ap.add_argument("files", nargs="+")
    a = ap.parse_args()
    for path in a.files:
        with open(path, encoding="utf-8") as f:
            text = f.read()
        if text.startswith(HEADER + "\n"):
            print(f"{path}: already a frame script of version 2")
            continue
        if text.startswith(HEADER_V1 + "\n"):
            with open(path, "w", encoding="utf-8") as f:
                f.write(from_v1(text))
            print(f"{path}: version 1 -> 2")
            continue
        new = convert(text)
        with open(path, "w", encoding="utf-8") as f:
            f.write(new)
        if a.mbconform and any(l.startswith("device ") for l in new.splitlines()):
            with tempfile.TemporaryDirectory() as tmp:
                r = subprocess.run([a.mbconform, "props", "--replay", path, "--out", tmp], capture_output=True, text=True)
                written = os.path.join(tmp, "regressions", os.path.basename(path))
                if r.returncode != 0 or not os.path.exists(written):
                    sys.exit(f"{path}: the model does not replay it ({r.returncode}):\n{r.stdout}{r.stderr}")
                shutil.copyfile(written, path)
        print(f"{path}: converted")


if __name__ == "__main__":
    main()
