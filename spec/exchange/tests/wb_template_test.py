#!/usr/bin/python3
"""wb-mqtt-serial device templates in and out (`spec import --wb-template`,
`spec export --format wb-template`), checked against the templates
themselves (read here with Python's json, not by the importer): every
channel whose format the spec language can state is a register with the
template's table, address, width, word order, scale and access; every bit
channel a field of its register's bitfield; every setup write an
operations.setup write; the timeouts the spec's timing. Each imported spec
passes `spec check`, is served by `serve`, and `run` against it passes;
exported and imported again it gives the same registers.

usage: wb_template_test.py MBCONFORM TEMPLATE_DIR WORK_DIR
"""
import glob
import json
import os
import shutil
import subprocess
import sys
import threading

MBC, TEMPLATES, WORK = sys.argv[1], sys.argv[2], sys.argv[3]
TABLE = {"holding": "holding", "holding_single": "holding", "holding_multi": "holding", "input": "input",
         "coil": "coil", "discrete": "discrete_input"}
WORDS = {"u16": 1, "s16": 1, "u8": 1, "s8": 1, "u32": 2, "s32": 2, "float": 2}
failures = []


def check(ok, what):
    if not ok:
        failures.append(what)
        print("FAIL", what, flush=True)


def mbc(*args, ok=True, timeout=600):
    p = subprocess.run([MBC, *args], capture_output=True, text=True, timeout=timeout)
    if ok and p.returncode != 0:
        failures.append(f"mbconform {' '.join(args)}: exit {p.returncode}\n{p.stdout[-2000:]}{p.stderr[-2000:]}")
    return p


def address(a):
    """(address, bit, width) of a template address: 16009, "16009", "0x3E89", "50199:9:1"."""
    if isinstance(a, int):
        return a, None, None
    parts = a.split(":")
    base = int(parts[0], 16) if parts[0].lower().startswith("0x") else int(parts[0])
    if len(parts) == 1:
        return base, None, None
    return base, int(parts[1]), int(parts[2]) if len(parts) > 2 else 1


def compare(name, template, spec):
    dev = template["device"]
    regs = {(r["table"], r["address"]): r for r in spec["registers"]}
    bitfields = {b["id"]: b for b in spec.get("bitfields", [])}
    channels = dev.get("channels", []) + (list(dev["parameters"].values()) if isinstance(dev.get("parameters"), dict)
                                          else dev.get("parameters", []))
    for c in channels:
        table = TABLE[c.get("reg_type", "holding")]
        a, bit, width = address(c["address"])
        at = f"{name} {c.get('name')} {table} {a}"
        r = regs.get((table, a))
        check(r is not None, f"{at}: no register")
        if r is None:
            continue
        if bit is not None:
            fields = bitfields.get(r.get("bitfield"), {}).get("fields", [])
            check(any(f["lo"] == bit and f["hi"] == bit + width - 1 for f in fields), f"{at}: no field for bits {bit}+{width}")
            continue
        fmt = c.get("format", "u16")
        if fmt not in WORDS:
            continue
        check(r["words"] == WORDS[fmt], f"{at}: {r['words']} words for format {fmt}")
        if WORDS[fmt] == 2:
            want = "low_first" if c.get("word_order") == "little_endian" else "high_first"
            check(r["word_order"] == want, f"{at}: word order {r['word_order']}, template {c.get('word_order')}")
        check(abs(r["scale"] - c.get("scale", 1)) < 1e-12, f"{at}: scale {r['scale']}, template {c.get('scale', 1)}")
        if c.get("readonly") and not any(s["address"] == a for s in dev.get("setup", [])):
            written = any(address(o["address"])[0] == a and address(o["address"])[1] is not None and not o.get("readonly")
                          for o in channels)
            check(r["access"] == "ro" or written, f"{at}: access {r['access']} of a read-only channel")
        if not c.get("readonly") and table in ("holding", "coil"):
            check(r["access"] in ("rw", "command"), f"{at}: access {r['access']} of a writable channel")
        if "units" in c:
            check(r["unit"] == c["units"], f"{at}: unit {r['unit']}")
        if "enum" in c:
            check(r["type"] == "enum", f"{at}: type {r['type']} for an enum channel")
    setups = spec["operations"]["setup"]
    check(len(setups) == len(dev.get("setup", [])), f"{name}: {len(setups)} setup writes, template {len(dev.get('setup', []))}")
    keys = {r["key"]: r for r in spec["registers"]}
    for s, w in zip(dev.get("setup", []), setups):
        r = keys.get(w["register"])
        check(r is not None and r["address"] == address(s["address"])[0] and w["value"] == s["value"],
              f"{name}: setup {s} became {w}")
    for k in ("response_timeout_ms", "frame_timeout_ms", "guard_interval_us"):
        check(spec["timing"][k] == dev.get(k), f"{name}: timing {k} {spec['timing'][k]}, template {dev.get(k)}")


def served_run(sid, specs):
    server = subprocess.Popen([MBC, "--spec-dir", specs, "serve", "--device", sid, "--tcp", "127.0.0.1:0"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    timer = threading.Timer(10, server.kill)
    timer.start()
    line = server.stdout.readline()
    timer.cancel()
    check(line.startswith("listening tcp "), f"{sid}: serve: {line!r}")
    if not line.startswith("listening tcp "):
        server.kill()
        return
    try:
        p = mbc("--spec-dir", specs, "run", "--quiet", "--device", sid, "--target", f"tcp://{line.split()[2]}",
                "--out", os.path.join(WORK, "run-" + sid), ok=False)
        print(p.stdout.splitlines()[-6:] if p.stdout else p.stderr)
        check(p.returncode == 0, f"{sid}: run against the served spec: exit {p.returncode}\n{p.stdout[-3000:]}{p.stderr[-1000:]}")
    finally:
        server.terminate()
        server.wait(timeout=10)


def main():
    shutil.rmtree(WORK, ignore_errors=True)
    specs = os.path.join(WORK, "specs")
    again = os.path.join(WORK, "again")
    os.makedirs(specs)
    os.makedirs(again)
    files = sorted(glob.glob(os.path.join(TEMPLATES, "*.json")))
    check(len(files) == 3, f"three templates: {files}")
    for f in files:
        template = json.load(open(f))
        name = os.path.basename(f)
        p = mbc("spec", "import", "--wb-template", f, "--out", "-")
        if p.returncode != 0:
            continue
        sid = p.stdout.split("\nmbconform_spec")[0].split("# ")[1].split(":")[0]
        path = os.path.join(specs, sid + ".yaml")
        open(path, "w").write(p.stdout)
        check(mbc("spec", "check", path).returncode == 0, f"{name}: spec check")
        spec = json.loads(mbc("--spec-dir", specs, "spec", "dump", sid, "--json").stdout)
        compare(name, template, spec)
        served_run(sid, specs)
        # Out and in again: the same registers.
        out = mbc("--spec-dir", specs, "spec", "export", sid, "--format", "wb-template").stdout
        exported = os.path.join(WORK, sid + ".json")
        open(exported, "w").write(out)
        back = mbc("spec", "import", "--wb-template", exported, "--id", sid, "--out", os.path.join(again, sid + ".yaml"))
        if back.returncode == 0:
            spec2 = json.loads(mbc("--spec-dir", again, "spec", "dump", sid, "--json").stdout)
            shape = lambda s: sorted((r["table"], r["address"], r["words"], r["type"], r["access"], r["scale"], r["word_order"])
                                     for r in s["registers"])
            check(shape(spec) == shape(spec2), f"{name}: exported and imported again, the registers differ")
            check(spec["operations"]["setup"] == spec2["operations"]["setup"] or
                  [(w["value"]) for w in spec["operations"]["setup"]] == [(w["value"]) for w in spec2["operations"]["setup"]],
                  f"{name}: setup differs after the round trip")
            check(spec["timing"] == {**spec2["timing"], "section": spec["timing"]["section"]}, f"{name}: timing differs after the round trip")
        print(f"{name}: {sid}: {len(spec['registers'])} registers, {len(spec['operations']['setup'])} setup writes")
    for f in failures:
        print("FAIL:", f)
    return 1 if failures else 0


sys.exit(main())
