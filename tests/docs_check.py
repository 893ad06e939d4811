#!/usr/bin/env python3
"""Checks that the README and docs/*.md still hold: every relative link resolves and every code block runs.

    python3 tests/docs_check.py --cli build/examples/perch2 --build-dir build --source-dir . \
        --python .venv/bin/python [--page docs/cli.md] [--links-only] [--verbose]

Links: every relative link or image of a page must name an existing file, and a `#anchor` a heading of the
target page (GitHub's slugs). Blocks: each page's fenced blocks run in order in one fresh work directory per
page (BUILD/docs_check/PAGE/, which holds symlinks `build`, `examples`, `bench`, `python`, `.venv` to the tree,
so commands read as they would from the repository root):

  ```sh / ```bash / ```console  through bash -euo pipefail (```console: only the lines after a "$ " prompt),
                                with `perch2` (the built CLI) and `python` (the venv's Python, PYTHONPATH =
                                BUILD/python) first on PATH, OMP_WAIT_POLICY=passive
  ```python                     through that Python
  ```cpp / ```c++               a block with a main() is compiled against the build tree (g++, the public
                                include folders, perch2's libraries) and run without arguments; any other
                                block is compiled with -fsyntax-only. Compiles run in the background, one
                                at a time, while the other blocks run
  ```text and other languages   shown, not run (output samples, CMake, JSON)

A block that cannot run here says why in an HTML comment on the line before its fence:
    <!-- docs-check: skip (needs a GPU) -->
and a block that needs an optional Python module says which, to be skipped (with that reason) without it:
    <!-- docs-check: needs python module ray -->
A skip without a reason, or a fence without a language, is a failure. The summary lists blocks run, skipped
(with their reasons) and failed; the exit status is 1 on any failure. Standard library only.
"""

import argparse
import os
import re
import shutil
import subprocess
import sys
import time
import unicodedata

RUN_SHELL = {"sh", "bash", "shell", "console"}
RUN_PYTHON = {"python", "py", "python3"}
RUN_CPP = {"cpp", "c++", "cxx"}
SKIP_RE = re.compile(r"^\s*<!--\s*docs-check:\s*skip\b(.*?)-->\s*$")
NEEDS_RE = re.compile(r"^\s*<!--\s*docs-check:\s*needs python module\s+([A-Za-z0-9_.]+)\s*-->\s*$")
FENCE_RE = re.compile(r"^(\s*)(`{3,}|~{3,})\s*([^`\s]*)\s*.*$")
LINK_RE = re.compile(r"!?\[(?:[^\]\[]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
HEADING_RE = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$")
BLOCK_TIMEOUT_S = 600


class Block:
    def __init__(self, page, line, lang, text, skip, needs=None):
        self.page, self.line, self.lang, self.text, self.skip = page, line, lang, text, skip
        self.needs = needs  # an optional Python module the block needs (skipped, saying so, without it)

    def where(self):
        return f"{self.page}:{self.line}"


def parse(path, rel):
    """Fenced blocks (with the skip note before each) and the prose lines (code fences removed)."""
    lines = open(path, encoding="utf-8").read().split("\n")
    blocks, prose, problems = [], [], []
    i = 0
    while i < len(lines):
        m = FENCE_RE.match(lines[i])
        if not m:
            prose.append((i + 1, lines[i]))
            i += 1
            continue
        indent, fence, lang = m.group(1), m.group(2), m.group(3).lower()
        start = i
        body = []
        i += 1
        while i < len(lines) and not (lines[i].strip().startswith(fence[0] * len(fence))
                                      and lines[i].strip().strip(fence[0]) == ""):
            body.append(lines[i][len(indent):] if lines[i].startswith(indent) else lines[i])
            i += 1
        if i == len(lines):
            problems.append(f"{rel}:{start + 1}: unclosed code fence")
        i += 1
        # The skip note: the last non-blank line before the fence.
        # The notes on the lines right before the fence (blank lines between are allowed).
        skip, needs = None, None
        k = start - 1
        while k >= 0 and (not lines[k].strip() or SKIP_RE.match(lines[k]) or NEEDS_RE.match(lines[k])):
            s, n = SKIP_RE.match(lines[k]), NEEDS_RE.match(lines[k])
            if s:
                reason = s.group(1).strip()
                if reason.startswith("(") and reason.endswith(")"):
                    reason = reason[1:-1].strip()
                skip = reason if reason else ""
            if n:
                needs = n.group(1)
            k -= 1
        if not lang:
            problems.append(f"{rel}:{start + 1}: a code fence without a language (use ```text for output)")
        blocks.append(Block(rel, start + 1, lang, "\n".join(body) + "\n", skip, needs))
    return blocks, prose, problems


def slug(heading, seen):
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens, -1, -2 for repeats."""
    text = re.sub(r"`([^`]*)`", r"\1", heading)
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", text)  # links keep their text
    text = re.sub(r"<[^>]+>", "", text).strip().lower()
    out = "".join(c for c in text if c in " -_" or unicodedata.category(c)[0] in "LN")
    out = out.replace(" ", "-")
    base, n = out, seen.get(out, 0)
    seen[base] = n + 1
    return base if n == 0 else f"{base}-{n}"


def anchors(path, cache):
    if path not in cache:
        seen, found = {}, set()
        _, prose, _ = parse(path, path)
        for _, line in prose:
            m = HEADING_RE.match(line)
            if m:
                found.add(slug(m.group(2), seen))
        cache[path] = found
    return cache[path]


def check_links(src, rel, prose, cache):
    problems, count = [], 0
    page_dir = os.path.dirname(os.path.join(src, rel))
    for number, line in prose:
        line = re.sub(r"`[^`]*`", "", line)  # links inside inline code are text
        for m in LINK_RE.finditer(line):
            target = m.group(1)
            if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I):  # http:, https:, mailto:
                continue
            count += 1
            path, _, anchor = target.partition("#")
            full = os.path.normpath(os.path.join(page_dir, path)) if path else os.path.join(src, rel)
            if not os.path.exists(full):
                problems.append(f"{rel}:{number}: link to {target}: {os.path.relpath(full, src)} does not exist")
                continue
            if anchor and full.endswith(".md") and anchor not in anchors(full, cache):
                problems.append(f"{rel}:{number}: link to {target}: no heading with the anchor #{anchor} in "
                                f"{os.path.relpath(full, src)}")
    return problems, count


def cmake_cache(build):
    values = {}
    try:
        for line in open(os.path.join(build, "CMakeCache.txt"), encoding="utf-8"):
            m = re.match(r"^([A-Za-z0-9_]+):[A-Z]+=(.*)$", line.strip())
            if m:
                values[m.group(1)] = m.group(2)
    except OSError:
        pass
    return values


class Runner:
    def __init__(self, a):
        self.a = a
        self.src, self.build = os.path.abspath(a.source_dir), os.path.abspath(a.build_dir)
        self.root = os.path.join(self.build, "docs_check")
        self.bin = os.path.join(self.root, "bin")
        shutil.rmtree(self.bin, ignore_errors=True)
        os.makedirs(self.bin)
        os.symlink(os.path.abspath(a.cli), os.path.join(self.bin, "perch2"))
        for name in ("python", "python3"):  # a wrapper, not a symlink: a venv is found from the path run
            with open(os.path.join(self.bin, name), "w") as f:
                f.write(f'#!/bin/sh\nexec "{a.python}" "$@"\n')
            os.chmod(os.path.join(self.bin, name), 0o755)
        self.env = dict(os.environ)
        self.env["PATH"] = self.bin + os.pathsep + self.env.get("PATH", "")
        self.env["PYTHONPATH"] = os.path.join(self.build, "python")
        self.env["PERCH2_CLI"] = os.path.abspath(a.cli)
        self.env["OMP_WAIT_POLICY"] = self.env.get("OMP_WAIT_POLICY", "passive")
        self.env.pop("VIRTUAL_ENV", None)
        cache = cmake_cache(self.build)
        self.cxx = a.cxx or cache.get("CMAKE_CXX_COMPILER") or "g++"
        self.includes = [os.path.join(self.src, p) for p in ("include", "backends/cpu/include",
                                                             "backends/cuda/include")]
        self.system_includes = ["/usr/include/eigen3"]
        cccl = cache.get("PERCH2_TOOLKIT_CCCL_DIR", "")
        if cccl and cache.get("PERCH2_FORCE_SYSTEM_CCCL", "OFF") in ("OFF", "0", "FALSE", "NO") and \
                os.path.isdir(cccl):
            self.system_includes.append(cccl)
        libs = []
        for folder in (self.build, os.path.join(self.build, "backends/cpu"), os.path.join(self.build, "backends/cuda")):
            if os.path.isdir(folder):
                libs.append(folder)
        self.lib_dirs = libs
        self.libs = []
        for name in ("perch2_runner", "perch2_eval", "perch2_dataset", "perch2_synth", "perch2_io", "perch2_cpu",
                     "perch2_thrust_omp"):
            if any(os.path.exists(os.path.join(d, f"lib{name}.so")) for d in libs):
                self.libs.append(name)

    def workdir(self, rel):
        d = os.path.join(self.root, re.sub(r"[^A-Za-z0-9_.-]", "_", rel))
        shutil.rmtree(d, ignore_errors=True)
        os.makedirs(d)
        for name in ("examples", "bench", "python", "include", "tests", "docs", ".venv"):
            if os.path.exists(os.path.join(self.src, name)):
                os.symlink(os.path.join(self.src, name), os.path.join(d, name))
        os.symlink(self.build, os.path.join(d, "build"))
        return d

    def cpp_commands(self, block, source):
        """The compile command for a C++ block, and the executable (None: a fragment, -fsyntax-only)."""
        flags = [f"-I{p}" for p in self.includes] + [x for p in self.system_includes for x in ("-isystem", p)]
        base = [self.cxx, "-std=c++17", "-fopenmp"] + flags
        if re.search(r"\bint\s+main\s*\(", block.text):
            exe = source[:-len(".cpp")]
            link = [f"-L{d}" for d in self.lib_dirs] + [f"-Wl,-rpath,{d}" for d in self.lib_dirs]
            return base + ["-O1", source, "-o", exe] + link + [f"-l{l}" for l in self.libs], exe
        return base + ["-fsyntax-only", source], None

    def start_compiles(self, jobs):
        """Compiles every C++ block in the background (one at a time), so that compiling overlaps the other
        blocks' runs; jobs: (block, source path). run() waits for a block's compile."""
        self.compiles = {}
        def work():
            for block, source in jobs:
                cmd, exe = self.cpp_commands(block, source)
                t0 = time.time()
                try:
                    p = subprocess.run(cmd, cwd=os.path.dirname(source), env=self.env, stdout=subprocess.PIPE,
                                       stderr=subprocess.STDOUT, timeout=BLOCK_TIMEOUT_S)
                    result = (p.returncode == 0, p.stdout.decode("utf-8", "replace"), time.time() - t0, exe)
                except subprocess.TimeoutExpired:
                    result = (False, f"compile timed out after {BLOCK_TIMEOUT_S} s", time.time() - t0, exe)
                self.compiles[source].put(result)
        import queue
        import threading
        for _, source in jobs:
            self.compiles[source] = queue.Queue()
        threading.Thread(target=work, daemon=True).start()

    def run(self, block, cwd, n, source=None):
        """Runs one block; returns (ok, seconds, output)."""
        t0 = time.time()
        if block.lang in RUN_CPP:
            ok, out, compile_s, exe = self.compiles[source].get()
            out = f"(compiled in {compile_s:.0f} s)\n" + out
            if not ok:
                return False, time.time() - t0, "compile failed\n" + out
            if exe is None:
                return True, time.time() - t0, out
            cmds = [[exe]]
        elif block.lang in RUN_SHELL:
            text = block.text
            if block.lang == "console":
                text = "\n".join(l[2:] for l in text.split("\n") if l.startswith("$ ")) + "\n"
            cmds = [["bash", "-euo", "pipefail", "-c", text]]
            out = ""
        else:
            script = os.path.join(cwd, f"block_{n:02d}.py")
            open(script, "w").write(block.text)
            cmds = [[self.a.python, script]]
            out = ""
        for cmd in cmds:
            try:
                p = subprocess.run(cmd, cwd=cwd, env=self.env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                   timeout=BLOCK_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                return False, time.time() - t0, out + f"timed out after {BLOCK_TIMEOUT_S} s"
            out += p.stdout.decode("utf-8", "replace")
            if p.returncode != 0:
                return False, time.time() - t0, f"exit status {p.returncode}\n" + out
        return True, time.time() - t0, out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cli", help="the built perch2 command-line tool")
    ap.add_argument("--build-dir", default="build")
    ap.add_argument("--source-dir", default=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    ap.add_argument("--python", default=sys.executable, help="a Python that has numpy (the build's venv)")
    ap.add_argument("--cxx", help="C++ compiler (default: the build's)")
    ap.add_argument("--page", action="append", help="check only this page (repeatable), e.g. docs/cli.md")
    ap.add_argument("--links-only", action="store_true", help="check the links, run nothing")
    ap.add_argument("--verbose", action="store_true", help="print every block's output")
    a = ap.parse_args()
    src = os.path.abspath(a.source_dir)
    pages = ["README.md"] + sorted(os.path.join("docs", f) for f in os.listdir(os.path.join(src, "docs"))
                                   if f.endswith(".md"))
    if a.page:
        pages = [os.path.normpath(p) for p in a.page]
    if not a.links_only and not a.cli:
        ap.error("--cli is required unless --links-only")

    failures, skipped, ran, shown = [], [], [], []
    cache = {}
    link_count = 0
    parsed = {}
    for rel in pages:
        blocks, prose, problems = parse(os.path.join(src, rel), rel)
        parsed[rel] = blocks
        failures += problems
        p, n = check_links(src, rel, prose, cache)
        failures += p
        link_count += n
        for b in blocks:
            if b.skip == "":
                failures.append(f"{b.where()}: a docs-check skip without a reason: say why, "
                                "<!-- docs-check: skip (REASON) -->")
    print(f"links: {link_count} relative links checked on {len(pages)} pages")

    if not a.links_only:
        runner = Runner(a)
        t_all = time.time()
        have = {}
        for rel in pages:
            for b in parsed[rel]:
                if b.needs and b.skip is None:
                    if b.needs not in have:
                        have[b.needs] = subprocess.run([a.python, "-c", f"import {b.needs}"], env=runner.env,
                                                       stdout=subprocess.DEVNULL,
                                                       stderr=subprocess.DEVNULL).returncode == 0
                    if not have[b.needs]:
                        b.skip = f"needs the Python module {b.needs}, which {a.python} does not have"
        todo, compiles = [], []  # (page, work dir, [(n, block, source)]) in order; C++ sources to compile
        for rel in pages:
            runnable = [(n, b) for n, b in enumerate(parsed[rel])
                        if b.skip is None and b.lang in RUN_SHELL | RUN_PYTHON | RUN_CPP]
            for b in parsed[rel]:
                if b.skip:
                    skipped.append((b, b.skip))
                elif b.skip is None and b.lang and b.lang not in RUN_SHELL | RUN_PYTHON | RUN_CPP:
                    shown.append(b)
            if not runnable:
                continue
            cwd = runner.workdir(rel)
            items = []
            for n, b in runnable:
                source = None
                if b.lang in RUN_CPP:
                    source = os.path.join(cwd, f"block_{n:02d}.cpp")
                    open(source, "w").write(b.text)
                    compiles.append((b, source))
                items.append((n, b, source))
            todo.append((rel, cwd, items))
        runner.start_compiles(compiles)
        for rel, cwd, items in todo:
            for n, b, source in items:
                ok, seconds, out = runner.run(b, cwd, n, source)
                status = "ok" if ok else "FAILED"
                print(f"  {status:6} {seconds:6.1f} s  {b.where()} ({b.lang})", flush=True)
                if a.verbose or not ok:
                    tail = out.strip().split("\n")[-40:]
                    print("\n".join("           | " + l for l in tail))
                ran.append((b, seconds))
                if not ok:
                    first = out.strip().splitlines()[0] if out.strip() else "no output"
                    failures.append(f"{b.where()}: the {b.lang} block failed ({first})")
        print(f"blocks: {len(ran)} run in {time.time() - t_all:.0f} s, {len(skipped)} skipped, "
              f"{len(shown)} shown only (text, cmake, json, ...)")
        for b, reason in skipped:
            print(f"  skipped {b.where()} ({b.lang}): {reason}")
    if failures:
        print(f"{len(failures)} failure(s):")
        for f in failures:
            print("  " + f)
        return 1
    print("docs check passed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
