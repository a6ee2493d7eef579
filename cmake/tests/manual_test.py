#!/usr/bin/python3
"""ctest cli_manual: the man page and the bash completion list every command and option.

The commands and options are read from `mbconform help [COMMAND...]` (CLI11's own help
text, walked from the top down); the man page is rendered with `man -l` (groff) and
the completion is run in bash with COMP_WORDS set as a shell would. Each help's usage
line names the program ("Usage: mbconform run [OPTIONS]").

usage: manual_test.py MBCONFORM [MAN_PAGE BASH_COMPLETION]
(the files the build wrote; default: generated now with `help --man` / `completion bash`)
"""
import os
import re
import shlex
import subprocess
import sys
import tempfile

mbc = sys.argv[1]
failures = []


def fail(what):
    failures.append(what)
    print("manual_test: FAIL:", what, file=sys.stderr)


def run(*args):
    p = subprocess.run([mbc, *args], capture_output=True, text=True, timeout=60)
    if p.returncode != 0:
        raise SystemExit(f"manual_test: mbconform {' '.join(args)}: exit {p.returncode}: {p.stderr}")
    return p.stdout


def parse_help(text):
    """(usage line, option names, subcommand names) of one CLI11 help text."""
    usage = next((l for l in text.splitlines() if l.startswith("Usage:")), "")
    options, subs, section = [], [], None
    for line in text.splitlines():
        if re.match(r"^(Options|Subcommands|Positionals):", line):
            section = line.split(":")[0]
            continue
        if not line.startswith("  ") or line.startswith("   " * 4):
            if line and not line.startswith(" "):
                section = None
            continue
        word = line.split()[0] if line.split() else ""
        if section == "Options" and word.startswith("-"):
            # "-q,--quiet", "--target TEXT ...": the names before the first space
            options += [n for n in word.split(",") if n.startswith("-")]
        elif section == "Subcommands" and word:
            subs.append(word)
    return usage, options, subs


# Walk every command from the help texts.
commands = {}  # "spec import" -> (options, subcommands)
todo = [[]]
while todo:
    path = todo.pop(0)
    usage, options, subs = parse_help(run("help", *path))
    want = "Usage: " + " ".join(["mbconform", *path])
    if not usage.startswith(want + " ") and usage != want:
        fail(f"help {' '.join(path)}: usage line {usage!r} does not start with {want!r}")
    commands[" ".join(path)] = (options, subs)
    todo += [path + [s] for s in subs]
n_options = sum(len(o) for o, _ in commands.values())
if len(commands) < 10 or n_options < 50:
    fail(f"only {len(commands)} commands and {n_options} options read from the help: the parser is broken")
for must in ["run", "serve", "check-capture", "restore", "spec import", "completion"]:
    if must not in commands:
        fail(f"help lists no command '{must}'")

# The man page, rendered by man(1) from the file.
man_file = sys.argv[2] if len(sys.argv) > 2 else None
with tempfile.TemporaryDirectory() as tmp:
    if not man_file:
        man_file = os.path.join(tmp, "mbconform.1")
        with open(man_file, "w") as f:
            f.write(run("help", "--man"))
    env = dict(os.environ, MANWIDTH="200", MANPAGER="cat", PAGER="cat", LANG="C.UTF-8")
    p = subprocess.run(["man", "-l", man_file], capture_output=True, text=True, env=env, timeout=60)
    if p.returncode != 0 or "warning" in p.stderr:
        fail(f"man -l {man_file}: exit {p.returncode}: {p.stderr.strip()}")
    page = re.sub(r".\x08", "", p.stdout)  # overstrike, if any
    for dash in "\u2010\u2011\u2212":  # groff's hyphen and minus, as typed
        page = page.replace(dash, "-")
    # Each command's section: from its heading to the next heading.
    sections = {}
    heads = [(m.start(), m.group(1)) for m in re.finditer(r"^MBCONFORM (.+)$", page, re.M)]
    for i, (at, name) in enumerate(heads):
        end = heads[i + 1][0] if i + 1 < len(heads) else len(page)
        sections[name.lower()] = page[at:end]
    glob = page[page.find("GLOBAL OPTIONS"):]
    for path, (options, subs) in commands.items():
        text = sections.get(path) if path else glob
        if text is None:
            fail(f"man page: no section 'MBCONFORM {path.upper()}'")
            continue
        if path and f"mbconform {path}" not in text:
            fail(f"man page: section {path} has no usage line 'mbconform {path} ...'")
        for o in options:
            if not re.search(r"(?<![\w-])" + re.escape(o) + r"(?![\w-])", text):
                fail(f"man page: option {o} of '{path or 'mbconform'}' is not in its section")
        for s in subs:
            if s not in text:
                fail(f"man page: '{path}' lists no command {s}")
    for code in ("0 success", "1 the check failed", "2 the command could not run"):
        if code not in re.sub(r"\s+", " ", page):
            fail(f"man page: EXIT STATUS lacks '{code}'")

    # The completion, run by bash.
    bash_file = sys.argv[3] if len(sys.argv) > 3 else os.path.join(tmp, "mbconform.bash")
    if len(sys.argv) <= 3:
        with open(bash_file, "w") as f:
            f.write(run("completion", "bash"))

    def complete(words):
        """COMPREPLY for `mbconform WORDS` with the cursor on the last word."""
        quoted = " ".join(shlex.quote(w) for w in words)
        script = (f"source {bash_file}\nCOMP_WORDS=(mbconform {quoted})\nCOMP_CWORD={len(words)}\n_mbconform\n"
                  "printf '%s\\n' \"${COMPREPLY[@]}\"\n")
        env = dict(os.environ, PATH=os.path.dirname(os.path.abspath(mbc)) + ":" + os.environ["PATH"])
        p = subprocess.run(["bash", "--norc", "--noprofile", "-c", script], capture_output=True, text=True, timeout=60,
                           env=env)
        if p.returncode != 0:
            fail(f"completion of {words}: bash exit {p.returncode}: {p.stderr.strip()}")
        return set(p.stdout.split())

    for path, (options, subs) in commands.items():
        words = path.split() if path else []
        got = complete(words + ["-"])
        for o in options:
            if o not in got:
                fail(f"completion: 'mbconform {path} -' does not offer {o}")
        if subs:
            got = complete(words + [""])
            for s in subs:
                if s not in got:
                    fail(f"completion: 'mbconform {path} ' does not offer the command {s}")
    # An option's value is not a command: `run --out spec -` still completes run's options.
    if "--target" not in complete(["run", "--out", "spec", "-"]):
        fail("completion: an option's value was taken for a command")
    if "hsc60" not in complete(["run", "--device", "hs"]):
        fail("completion: --device does not complete the spec ids")

if failures:
    sys.exit(f"manual_test: {len(failures)} failure(s)")
print(f"manual_test: ok ({len(commands)} commands, {n_options} options in the help, the man page and the completion)")
