#!/usr/bin/env python3
"""ctest exchange_export_*: every device's exports, read back with real
parsers (Python's csv module and PyYAML), compared register by register
with the resolved spec (`mbconform spec dump ID --json`); the Home Assistant
keys checked against the modbus integration's schema; `spec import` of a bad
CSV writes nothing.

usage: export_test.py MBCONFORM FORMAT WORK_DIR     FORMAT: csv | home-assistant | edgex | import
"""
import csv
import io
import json
import os
import shutil
import subprocess
import sys

import yaml

MBC, FORMAT, WORK = sys.argv[1], sys.argv[2], sys.argv[3]
failures = []


def run(*args, ok=True):
    p = subprocess.run([MBC, *args], capture_output=True, text=True)
    if ok and p.returncode != 0:
        sys.exit(f"mbconform {' '.join(args)}: exit {p.returncode}\n{p.stderr}")
    return p


def check(cond, what):
    if not cond:
        failures.append(what)


def wire_type(r):
    if r["type"] in ("enum", "bitfield"):
        return "u32" if r["words"] == 2 else "u16"
    return r["type"]


def specs():
    for line in run("spec", "list").stdout.splitlines():
        sid = line.split()[0]
        yield sid, json.loads(run("spec", "dump", sid, "--json").stdout)


CSV_TABLES = {"coil": "coil", "discrete input": "discrete_input", "input register": "input", "holding register": "holding"}


def test_csv(sid, spec):
    rows = list(csv.DictReader(io.StringIO(run("spec", "export", sid, "--format", "csv").stdout)))
    regs = spec["registers"]
    check(len(rows) == len(regs), f"{sid}: {len(rows)} CSV rows for {len(regs)} registers")
    for row, r in zip(rows, regs):
        at = f"{sid} {r['table']} {r['address']:#06x}"
        check(CSV_TABLES[row["table"]] == r["table"], f"{at}: table {row['table']}")
        check(int(row["address"], 16) == r["address"], f"{at}: address {row['address']}")
        check(row["name"] == r["name"], f"{at}: name {row['name']!r}")
        check(row["access"] == r["access"], f"{at}: access {row['access']}")
        check(row["type"] == wire_type(r), f"{at}: type {row['type']}")
        check(int(row["words"]) == r["words"], f"{at}: words {row['words']}")
        check((row["word_order"] or None) == r["word_order"], f"{at}: word_order {row['word_order']!r}")
        rng = r["range"]
        check((float(row["min"]) if row["min"] else None) == (rng["min"] if rng else None), f"{at}: min {row['min']}")
        check((float(row["max"]) if row["max"] else None) == (rng["max"] if rng else None), f"{at}: max {row['max']}")
        check((float(row["default"]) if row["default"] else None) == r["default"], f"{at}: default {row['default']}")
        check(row["unit"] == r["unit"], f"{at}: unit {row['unit']!r}")
        check(float(row["scale"] or 1) == r["scale"], f"{at}: scale {row['scale']}")


# The modbus integration's YAML schema, Home Assistant 2024 releases
# (homeassistant/components/modbus/__init__.py: MODBUS_SCHEMA,
# BASE_COMPONENT_SCHEMA, BASE_STRUCT_SCHEMA, SENSOR_SCHEMA,
# BINARY_SENSOR_SCHEMA, SWITCH_SCHEMA; `device_address` since 2023.10).
HA_HUB = {"name", "type", "port", "host", "baudrate", "bytesize", "method", "parity", "stopbits", "timeout", "delay",
          "message_wait_milliseconds"}
HA_PLATFORMS = {"binary_sensors", "climates", "covers", "fans", "lights", "sensors", "switches"}  # no `numbers`
HA_BASE = {"name", "address", "device_address", "slave", "scan_interval", "unique_id"}
HA_STRUCT = HA_BASE | {"input_type", "count", "data_type", "structure", "scale", "offset", "precision", "swap"}
HA_KEYS = {
    "sensors": HA_STRUCT | {"device_class", "state_class", "unit_of_measurement", "virtual_count", "slave_count",
                            "min_value", "max_value", "nan_value", "zero_suppress"},
    "binary_sensors": HA_BASE | {"device_class", "input_type", "virtual_count", "slave_count"},
    "switches": HA_BASE | {"write_type", "command_on", "command_off", "verify", "device_class"},
}
HA_VALUES = {
    ("sensors", "input_type"): {"holding", "input"},
    ("sensors", "data_type"): {"int16", "int32", "int64", "uint16", "uint32", "uint64", "float16", "float32", "float64",
                               "string", "custom"},
    ("sensors", "swap"): {"byte", "word", "word_byte"},
    ("binary_sensors", "input_type"): {"coil", "discrete_input", "holding", "input"},
    ("switches", "write_type"): {"holding", "coil", "x_coil", "x_holding"},
}
HA_VERIFY = {"address", "input_type", "state_on", "state_off", "delay"}
HA_DATA = {"u16": "uint16", "s16": "int16", "u32": "uint32", "s32": "int32", "f32": "float32"}


def test_home_assistant(sid, spec):
    text = run("spec", "export", sid, "--format", "home-assistant").stdout
    doc = yaml.safe_load(text)
    hubs = doc["modbus"]
    check(isinstance(hubs, list) and len(hubs) == 1, f"{sid}: modbus: is not a list of one hub")
    hub = hubs[0]
    check(set(hub) <= HA_HUB | HA_PLATFORMS, f"{sid}: hub keys outside the schema: {set(hub) - HA_HUB - HA_PLATFORMS}")
    check(hub["type"] == "serial" and hub["method"] == "rtu", f"{sid}: hub type/method")
    check(hub["parity"] in ("E", "O", "N") and hub["bytesize"] in (5, 6, 7, 8) and hub["stopbits"] in (1, 2),
          f"{sid}: serial settings {hub['parity']} {hub['bytesize']} {hub['stopbits']}")
    check(hub["baudrate"] == (spec["serial"]["baud_rates"]["default"] or spec["serial"]["baud_rates"]["values"][0]),
          f"{sid}: baudrate {hub['baudrate']}")
    entities = {}
    names = set()
    for platform in HA_PLATFORMS & set(hub):
        for e in hub[platform]:
            check(set(e) <= HA_KEYS[platform], f"{sid} {platform}: keys outside the schema: {set(e) - HA_KEYS[platform]}")
            for (p, key), allowed in HA_VALUES.items():
                if p == platform and key in e:
                    check(e[key] in allowed, f"{sid} {platform} {e['name']}: {key}: {e[key]} not in the schema")
            if "verify" in e:
                check(set(e["verify"]) <= HA_VERIFY, f"{sid}: verify keys {set(e['verify'])}")
            check(e["name"] not in names, f"{sid}: duplicate entity name {e['name']}")
            names.add(e["name"])
            table = {"sensors": e.get("input_type", "holding"), "switches": "coil"}.get(platform) or \
                {"coil": "coil", "discrete_input": "discrete_input"}.get(e.get("input_type", "coil"))
            entities[(table, e["address"])] = (platform, e)
    for r in spec["registers"]:
        at = f"{sid} {r['table']} {r['address']:#06x}"
        key = (r["table"], r["address"])
        readable = r["access"] in ("ro", "rw")
        if r["table"] in ("coil", "discrete_input"):
            want = "switches" if r["table"] == "coil" and r["access"] != "ro" else "binary_sensors"
        elif readable:
            want = "sensors"
        else:
            want = None  # write-only: no entity; listed with the write_register action
            check(f"#   0x{r['address']:04X} " in text, f"{at}: write-only register not listed with the write action")
        if want is None:
            check(key not in entities, f"{at}: a write-only register became an entity")
            continue
        if key not in entities:
            check(False, f"{at}: no entity")
            continue
        platform, e = entities[key]
        check(platform == want, f"{at}: {platform}, expected {want}")
        check(e["device_address"] == (spec["serial"]["slave_id"]["default"] or 1), f"{at}: device_address")
        if platform == "sensors":
            check(e["data_type"] == HA_DATA[wire_type(r)], f"{at}: data_type {e['data_type']}")
            check(e.get("swap") == ("word" if r["word_order"] == "low_first" else None), f"{at}: swap {e.get('swap')}")
            check(float(e.get("scale", 1)) == r["scale"], f"{at}: scale {e.get('scale')}")
            check(e.get("unit_of_measurement", "") == r["unit"], f"{at}: unit {e.get('unit_of_measurement')}")
        if platform == "switches":
            check(e["write_type"] == "coil", f"{at}: write_type {e['write_type']}")
        # Polled: what the drive changes by itself often, settings seldom.
        check(isinstance(e.get("scan_interval"), int) and e["scan_interval"] > 0, f"{at}: scan_interval {e.get('scan_interval')}")
        if platform == "sensors":
            numeric = r["type"] not in ("enum", "bitfield")
            if r["access"] == "ro" and numeric:
                check(e.get("state_class") in ("measurement", "total_increasing"), f"{at}: state_class {e.get('state_class')}")
                check(e["scan_interval"] < 60, f"{at}: a read-only value polled every {e['scan_interval']} s")
            else:
                check("state_class" not in e, f"{at}: a setting or coded value has state_class {e.get('state_class')}")
    check("modbus.write_register" in text, f"{sid}: the write_register action is not documented")
    # --only: the registers it names and nothing else.
    first = next(r for r in spec["registers"] if r["access"] in ("ro", "rw"))
    only = run("spec", "export", sid, "--format", "home-assistant", "--only", f"{first['address']:#06x}").stdout
    kept = [e for p in HA_PLATFORMS for e in (yaml.safe_load(only)["modbus"][0].get(p) or [])]
    check(kept and all(e["address"] == first["address"] for e in kept), f"{sid}: --only {first['address']:#06x} kept {[e['address'] for e in kept]}")
    none = run("spec", "export", sid, "--format", "home-assistant", "--only", "no-such-register-*", ok=False)
    check(none.returncode == 2 and "matches none" in none.stderr, f"{sid}: --only matching nothing: exit {none.returncode} {none.stderr!r}")


EDGEX_TABLES = {"COILS": "coil", "DISCRETES_INPUT": "discrete_input", "INPUT_REGISTERS": "input",
                "HOLDING_REGISTERS": "holding"}
EDGEX_RAW = {"u16": "UINT16", "s16": "INT16", "u32": "UINT32", "s32": "INT32", "f32": "FLOAT32"}
EDGEX_RW = {"ro": "R", "rw": "RW", "wo": "W", "command": "W"}


def test_edgex(sid, spec):
    doc = yaml.safe_load(run("spec", "export", sid, "--format", "edgex").stdout)
    check(doc["apiVersion"] == "v3" and doc["name"] == sid, f"{sid}: apiVersion/name")
    res = doc["deviceResources"]
    check(len(res) == len(spec["registers"]), f"{sid}: {len(res)} resources")
    check(len({x["name"] for x in res}) == len(res), f"{sid}: resource names are not unique")
    for x, r in zip(res, spec["registers"]):
        at = f"{sid} {r['table']} {r['address']:#06x}"
        a, p = x["attributes"], x["properties"]
        check(EDGEX_TABLES[a["primaryTable"]] == r["table"], f"{at}: primaryTable {a['primaryTable']}")
        check(a["startingAddress"] == r["address"], f"{at}: startingAddress {a['startingAddress']}")
        check(p["readWrite"] == EDGEX_RW[r["access"]], f"{at}: readWrite {p['readWrite']}")
        check(p.get("units", "") == r["unit"], f"{at}: units")
        check(float(p.get("scale", 1)) == r["scale"], f"{at}: scale")
        if r["type"] == "bit":
            check(p["valueType"] == "Bool" and "rawType" not in a, f"{at}: a bit is Bool")
            continue
        check(a["rawType"] == EDGEX_RAW[wire_type(r)], f"{at}: rawType {a['rawType']}")
        if r["words"] == 2:
            check(a["isWordSwap"] == (r["word_order"] == "low_first"), f"{at}: isWordSwap {a['isWordSwap']}")
        else:
            check("isWordSwap" not in a, f"{at}: isWordSwap on a 1-word register")
        if r["range"]:
            check(abs(p["minimum"] - r["range"]["min"] * r["scale"]) < 1e-9, f"{at}: minimum {p['minimum']}")
            check(abs(p["maximum"] - r["range"]["max"] * r["scale"]) < 1e-9, f"{at}: maximum {p['maximum']}")


def test_import():
    shutil.rmtree(WORK, ignore_errors=True)
    os.makedirs(WORK)
    example = os.path.join(os.path.dirname(os.path.abspath(__file__)), "example.csv")
    out = os.path.join(WORK, "acme-x1.yaml")
    run("spec", "import", "--csv", example, "--id", "acme-x1", "--out", out)
    p = run("spec", "check", out, ok=False)
    check(p.returncode == 0, f"the imported skeleton fails spec check: {p.stderr}")
    listed = run("spec", "list", "--spec-dir", WORK).stdout
    check("acme-x1" in listed and "(--spec-dir)" in listed, "the imported spec is not listed from --spec-dir")
    bad = os.path.join(WORK, "bad.csv")
    with open(bad, "w") as f:
        f.write("address,name,access\n0x10,Speed,rw\n0x10,Again,rw\n")
    out = os.path.join(WORK, "bad.yaml")
    p = run("spec", "import", "--csv", bad, "--id", "bad", "--out", out, ok=False)
    check(p.returncode == 1, f"bad CSV: exit {p.returncode}")
    check(f"{bad}:3: error: holding register 0x0010 is also on line 2" in p.stderr, f"bad CSV: stderr {p.stderr!r}")
    check(not os.path.exists(out), "bad CSV: a spec was written")

    # A vendor's sheet in GBK Chinese: the roles printed (read from the rows'
    # names by hand), the spec they make passes spec check, and with --out and
    # no --id the id is the file's name.
    here = os.path.dirname(os.path.abspath(__file__))
    out = os.path.join(WORK, "vfd-zh.yaml")
    p = run("spec", "import", "--csv", os.path.join(here, "vendor-vfd-gbk.csv"), "--out", out)
    table = {}
    for line in p.stderr.splitlines():
        if line.startswith("holding register 0x"):
            f = line.split()
            table[f[2]] = f[4]
    check(table == {"0x1000": "slave-address", "0x1001": "baud", "0x1002": "parity", "0x1003": "frame-format",
                    "0x2000": "motion", "0x2001": "motion", "0x2003": "none", "0x3001": "motion", "0x4000": "save",
                    "0x4001": "factory-reset", "0x4002": "motion"}, f"GBK sheet: roles {table}")
    p = run("spec", "check", out, ok=False)
    check(p.returncode == 0, f"the GBK sheet's spec fails spec check: {p.stderr}")
    dump = json.loads(run("spec", "dump", out, "--json").stdout)
    check(dump["device"]["manual"]["source"] == "csv", "GBK sheet: source")
    check(sorted(st["register"] for st in dump["serial"]["settings"]) == [0x1000, 0x1001, 0x1002, 0x1003],
          f"GBK sheet: serial.settings {dump['serial']['settings']}")

    # A wb-mqtt-serial template written under another name (issue 40): the id follows --out.
    template = os.path.join(here, "wb-mqtt-serial", "config-mst-24.json")
    out = os.path.join(WORK, "my-stepper.yaml")
    p = run("spec", "import", "--wb-template", template, "--out", out)
    p = run("spec", "check", out, ok=False)
    check(p.returncode == 0, f"--out my-stepper.yaml: spec check fails: {p.stderr}")
    out = os.path.join(WORK, "other.yaml")
    p = run("spec", "import", "--wb-template", template, "--id", "mst", "--out", out)
    check("warning: the spec's id is mst, so `spec check` wants the file named mst.yaml" in p.stderr,
          f"--id mst --out other.yaml: no warning: {p.stderr!r}")

    # CSV formula injection: an exported cell that starts with = + - @ is text
    # to Python's csv module and a spreadsheet ('=...), and imports back.
    sheet = os.path.join(WORK, "formula.csv")
    with open(sheet, "w") as f:
        f.write('address,name,access,unit,description\n0x10,"=HYPERLINK(""http://x"")",rw,@u,-2+3\n0x11,Speed,rw,,\n')
    out = os.path.join(WORK, "formula.yaml")
    run("spec", "import", "--csv", sheet, "--out", out)
    exported = run("spec", "export", out, "--format", "csv").stdout
    rows = list(csv.DictReader(io.StringIO(exported)))
    check(rows[0]["name"] == "'=HYPERLINK(\"http://x\")", f"formula name exported as {rows[0]['name']!r}")
    check(rows[0]["unit"] == "'@u" and rows[0]["description"] == "'-2+3", f"formula cells exported as {rows[0]!r}")
    back = os.path.join(WORK, "formula-back.csv")
    with open(back, "w") as f:
        f.write(exported)
    run("spec", "import", "--csv", back, "--out", os.path.join(WORK, "formula-back.yaml"))
    again = json.loads(run("spec", "dump", os.path.join(WORK, "formula-back.yaml"), "--json").stdout)
    check(again["registers"][0]["name"] == '=HYPERLINK("http://x")' and again["registers"][0]["unit"] == "@u",
          f"formula cells read back as {again['registers'][0]!r}")


if FORMAT == "import":
    test_import()
else:
    tests = {"csv": test_csv, "home-assistant": test_home_assistant, "edgex": test_edgex}
    n = 0
    for sid, spec in specs():
        tests[FORMAT](sid, spec)
        n += 1
    print(f"{FORMAT}: {n} specs compared register by register")
for f in failures[:50]:
    print("FAIL:", f)
sys.exit(1 if failures else 0)
