#!/usr/bin/env python3
"""No registry release can change what the set-up installs.

Checks every registry tools/setup.sh and the build reach (see the table in
tools/setup.sh):

  npm     conformance/peers/package.json + package-lock.json: every dependency
          spec in the lock that a future release could re-resolve (a dist-tag
          such as "latest" or "next", "*", "x", "", an open range such as
          ">=1.2" with no upper bound, a git or URL spec without a commit) must
          be pinned by an `overrides` entry in package.json that names exactly
          the locked version. `npm ci` resolves a dist-tag against the registry
          on every run, so a new release fails the lock check (EUSAGE "lock
          file's X does not satisfy Y"); a bounded range (^1.2, ~1.2, 1.x,
          ">=1 <2") is kept at the locked version.
  Go      Debian's packages in GOPATH mode: every `go build` in the CMake files
          runs with GO111MODULE=off and GOPROXY=off, and no go.mod/go.sum is
          committed (module mode would reach the module proxy).
  Python  Debian's packages, run by /usr/bin/python3: no pip install, no
          requirements or pyproject dependency files.

Usage: check-pins.py [--root DIR] [--npm-dir DIR]      exit 0 clean, 1 findings
       check-pins.py --self-test                        plants re-resolvable
           specs in a copy of the lock and checks each is named (exit 0 when
           the checker catches every planted one)
"""
import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile

DIST_TAG = re.compile(r"^[A-Za-z][A-Za-z0-9._-]*$")  # latest, next, beta (not a version)
COMMIT = re.compile(r"#[0-9a-f]{40}$")


def spec_problem(spec):
    """Why `spec` could resolve to another version after a future release, or None."""
    s = spec.strip()
    if s in ("", "*", "x", "X"):
        return "any version ('%s')" % s
    if s.startswith(("npm:",)):
        return spec_problem(s.rsplit("@", 1)[-1]) if "@" in s[4:] else "alias without a version"
    if s.startswith(("git", "http:", "https:", "github:")) or "/" in s and not s.startswith(("file:", ".")):
        return None if COMMIT.search(s) else "a git/URL spec without a commit"
    if s.startswith(("file:", "link:", ".")):
        return None
    if DIST_TAG.match(s) and not re.match(r"^v?\d", s):
        return "a dist-tag ('%s'), resolved against the registry on every install" % s
    for alt in s.split("||"):
        alt = alt.strip()
        if alt in ("", "*", "x", "X"):
            return "an alternative matching any version"
        parts = alt.split()
        # hyphen ranges "1 - 2" are bounded; comparator sets need an upper bound
        if "-" in parts and len(parts) == 3:
            continue
        lower_only = all(p.startswith(">") for p in parts) and parts
        if lower_only:
            return "an open range ('%s') with no upper bound" % alt
    return None


def check_npm(npm_dir):
    findings = []
    pj_path = os.path.join(npm_dir, "package.json")
    lock_path = os.path.join(npm_dir, "package-lock.json")
    try:
        with open(pj_path, encoding="utf-8") as f:
            pj = json.load(f)
        with open(lock_path, encoding="utf-8") as f:
            lock = json.load(f)
    except (OSError, ValueError) as e:
        return ["npm: cannot read %s: %s" % (npm_dir, e)]
    overrides = pj.get("overrides", {})
    packages = lock.get("packages", {})
    if not packages:
        return ["npm: %s has no 'packages' (lockfileVersion 2 or 3 expected)" % lock_path]
    locked = {}  # name -> set of locked versions
    for path, meta in packages.items():
        if not path:
            continue
        name = path.rsplit("node_modules/", 1)[-1]
        locked.setdefault(name, set()).add(meta.get("version", "?"))

    def where(path):
        return path or "package.json"

    for path, meta in packages.items():
        peer_meta = meta.get("peerDependenciesMeta", {})
        for section in ("dependencies", "optionalDependencies", "peerDependencies"):
            for name, spec in (meta.get(section) or {}).items():
                why = spec_problem(spec)
                if not why:
                    continue
                if section == "peerDependencies" and peer_meta.get(name, {}).get("optional") and name not in locked:
                    continue  # an optional peer nobody installs is never resolved
                pin = overrides.get(name)
                if isinstance(pin, dict):
                    pin = pin.get(".")
                if pin is None:
                    findings.append("npm: %s declares %s '%s' in %s: %s; pin it with \"overrides\": {\"%s\": \"%s\"} in %s"
                                    % (where(path), name, spec, section, why, name,
                                       "/".join(sorted(locked.get(name, {"<locked version>"}))), pj_path))
                elif name in locked and locked[name] != {pin}:
                    findings.append("npm: override %s '%s' is not the locked version %s" %
                                    (name, pin, "/".join(sorted(locked[name]))))
                elif spec_problem(pin):
                    findings.append("npm: override %s '%s' is itself %s" % (name, pin, spec_problem(pin)))
    return findings


def git_files(root):
    try:
        out = subprocess.run(["git", "-C", root, "ls-files", "-z"], check=True, capture_output=True).stdout
        return [p for p in out.decode().split("\0") if p]
    except (OSError, subprocess.CalledProcessError):
        files = []
        for d, dirs, names in os.walk(root):
            dirs[:] = [x for x in dirs if not x.startswith((".", "build"))]
            files += [os.path.relpath(os.path.join(d, n), root) for n in names]
        return files


def check_go_python(root):
    findings = []
    files = git_files(root)
    for rel in files:
        base = os.path.basename(rel)
        if base in ("go.mod", "go.sum"):
            findings.append("go: %s is committed: module mode reaches the module proxy (build in GOPATH mode from Debian's packages)" % rel)
        if base in ("requirements.txt", "Pipfile", "poetry.lock", "setup.py") or base == "pyproject.toml":
            findings.append("python: %s is committed: Python comes from Debian's packages" % rel)
    script_like = re.compile(r"(CMakeLists\.txt|\.cmake|\.sh|\.py|/run)$")
    for rel in files:
        if not script_like.search(rel) or rel.startswith("tools/check-pins.py"):
            continue
        try:
            with open(os.path.join(root, rel), encoding="utf-8", errors="replace") as f:
                text = f.read()
        except OSError:
            continue
        for n, line in enumerate(text.splitlines(), 1):
            code = line.split("#", 1)[0] if not rel.endswith("CMakeLists.txt") else line
            if re.search(r"\bpip3?\s+install\b|-m\s+pip\s+install", code):
                findings.append("python: %s:%d runs pip install: Python packages come from Debian" % (rel, n))
            if re.search(r"\bgo\s+(get|install|mod\s+download)\b", code):
                findings.append("go: %s:%d fetches Go modules: build from Debian's packages in GOPATH mode" % (rel, n))
            if re.search(r"\bCOMMAND\b.*\bgo\b.*\bbuild\b|\$\{MBC_GO\S*\}\s+build|\bgo\s+build\b", code):
                if not ("GO111MODULE=off" in text and "GOPROXY=off" in text):
                    findings.append("go: %s:%d builds Go without GO111MODULE=off and GOPROXY=off" % (rel, n))
    return findings


def self_test(npm_dir):
    """Plants re-resolvable specs in a copy of the lock; the checker must name each."""
    planted = {"mbc-planted-latest": "latest", "mbc-planted-star": "*", "mbc-planted-open": ">=1.0.0",
               "mbc-planted-next": "next", "mbc-planted-union": "^1.0.0 || >=3"}
    failures = []
    with tempfile.TemporaryDirectory() as tmp:
        shutil.copy(os.path.join(npm_dir, "package.json"), tmp)
        with open(os.path.join(npm_dir, "package-lock.json"), encoding="utf-8") as f:
            lock = json.load(f)
        if check_npm(npm_dir):
            failures.append("the committed lock is not clean to begin with")
        victim = next(p for p in lock["packages"] if p)
        lock["packages"][victim].setdefault("dependencies", {}).update(planted)
        with open(os.path.join(tmp, "package-lock.json"), "w", encoding="utf-8") as f:
            json.dump(lock, f)
        found = check_npm(tmp)
        for name, spec in planted.items():
            if not any(("%s '%s'" % (name, spec)) in line for line in found):
                failures.append("planted %s '%s' in %s was not reported" % (name, spec, victim))
        # A bounded range, an exact version and a pinned dist-tag are not findings.
        for spec in ("^1.2.3", "~1.2.3", "1.x", ">=1.7.1 <7", "1.2.3", "1 - 2"):
            if spec_problem(spec):
                failures.append("bounded spec '%s' reported: %s" % (spec, spec_problem(spec)))
        # The override of the committed package.json pins what it must: removing it must fail.
        with open(os.path.join(tmp, "package.json"), encoding="utf-8") as f:
            pj = json.load(f)
        if pj.pop("overrides", None):
            with open(os.path.join(tmp, "package.json"), "w", encoding="utf-8") as f:
                json.dump(pj, f)
            shutil.copy(os.path.join(npm_dir, "package-lock.json"), tmp)
            if not check_npm(tmp):
                failures.append("without its overrides the committed lock passed")
    for f in failures:
        print("self-test: " + f)
    print("self-test: %s" % ("FAILED" if failures else "every planted spec was named"))
    return 1 if failures else 0


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", default=os.path.dirname(here))
    ap.add_argument("--npm-dir")
    ap.add_argument("--self-test", action="store_true")
    a = ap.parse_args()
    npm_dir = a.npm_dir or os.path.join(a.root, "conformance", "peers")
    if a.self_test:
        return self_test(npm_dir)
    findings = check_npm(npm_dir) + check_go_python(a.root)
    for f in findings:
        print(f)
    print("pins: %d finding(s)" % len(findings) if findings else "pins: npm, Go and Python dependencies are pinned")
    return 1 if findings else 0


if __name__ == "__main__":
    sys.exit(main())
