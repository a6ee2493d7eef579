#!/usr/bin/python3
"""ctest readme_first_page: the README's first screen (40 lines) is what a newcomer needs.

It holds the two set-up commands (the main job, the tests), each a script of this tree
that exists and is executable; a command for a drive (`mbconform run --target ...
--device ...`), which the built mbconform accepts (run with --list, which opens nothing
and sends nothing); and the
exit codes 0, 1, 2 and 3. Every file the README links to exists.

usage: readme_test.py SOURCE_DIR MBCONFORM
"""
import os
import re
import shlex
import subprocess
import sys

src, mbc = sys.argv[1], sys.argv[2]
text = open(os.path.join(src, "README.md"), encoding="utf-8").read()
first = text.splitlines()[:40]
screen = "\n".join(first)
failures = []


def fail(what):
    failures.append(what)
    print("readme_test: FAIL:", what, file=sys.stderr)


commands = [l.strip() for l in first if re.match(r"^(tools/|build/bin/mbconform |mbconform )", l.strip())]
for script in ("tools/main-job.sh", "tools/test.sh"):
    if script not in commands:
        fail(f"the first 40 lines do not give the set-up command {script} on a line of its own")
    elif not os.access(os.path.join(src, script), os.X_OK):
        fail(f"{script} is not an executable file of this tree")
    elif "tools/setup.sh" not in open(os.path.join(src, script)).read():
        fail(f"{script} does not set the machine up (it never calls tools/setup.sh)")
if commands[:2] != ["tools/main-job.sh", "tools/test.sh"]:
    fail(f"the first two commands are {commands[:2]}, not the main job and the tests")

drive = [c for c in commands if re.search(r"mbconform run .*--target '?(rtu|tcp|rtu-tcp|mbtls)://", c) and "--device" in c]
if not drive:
    fail("the first 40 lines give no command for a drive (mbconform run --target URI --device ID)")
else:
    # The drive command parses: --list names its cases without opening the line.
    words = shlex.split(drive[0])
    words = [w for w in words[1:] if w != "--plan"]
    p = subprocess.run([mbc, *words, "--list"], capture_output=True, text=True, timeout=120)
    if p.returncode != 0 or len(p.stdout.splitlines()) < 10:
        fail(f"{drive[0]} --list: exit {p.returncode}, {len(p.stdout.splitlines())} cases: {p.stderr.strip()}")

for code, word in (("0", "pass"), ("1", "MUST"), ("2", "could not"), ("3", "--require-complete")):
    if not re.search(rf"`{code}`.*{re.escape(word)}", screen):
        fail(f"the first 40 lines do not give exit code {code} ({word})")

for target in re.findall(r"\]\(([^)#]+)\)", text):
    if not re.match(r"^[a-z]+:", target) and not os.path.exists(os.path.join(src, target)):
        fail(f"the README links to {target}, which does not exist")

if failures:
    sys.exit(f"readme_test: {len(failures)} failure(s)")
print(f"readme_test: ok ({len(commands)} commands on the first screen)")
