#!/usr/bin/env python3
"""Docstrings for the Python bindings from perch2's C++ headers (run by CMake at build time).

The headers document every struct, field, enumerator and function with Doxygen-style comments:
``/// text`` on the lines before a declaration, ``///< text`` after it (on its line, or continued on the
lines below). This script reads those comments and writes a C++ header of (key, text) pairs that the
bindings attach, so the Python docs are the C++ docs and are never re-typed. Keys name the declaration by
its enclosing classes, without namespaces: ``TabletopSettings``, ``TabletopSettings.xy_step_m``,
``KnnMethod.Grid``, ``TabletopEstimator.estimate``, ``observed_cloud``. A header's leading ``//`` comment
is kept as ``file:perch2/search/tabletop.hpp``. When two declarations share a key the first header given
wins (list the reference backend's headers before others).

    header_docs.py --out perch2_docs.hpp --root include include/perch2/core/camera.hpp ...
"""

import argparse
import os
import re
import sys

_CLASS_HEAD = re.compile(r"\b(?:struct|class|union)\s+(?:PERCH2_API\s+)?([A-Za-z_]\w*)\s*(?::[^{]*)?$")
_ENUM_HEAD = re.compile(r"\benum\s+(?:class\s+|struct\s+)?([A-Za-z_]\w*)?\s*(?::[\w\s:]*)?$")
_NAMESPACE_HEAD = re.compile(r"\bnamespace\b[\w\s:]*$")
_IDENT = re.compile(r"[A-Za-z_]\w*")
_SKIP_STATEMENT = re.compile(r"^(?:using|typedef|friend|static_assert|template\s*<[^>]*>\s*using)\b")


def _strip_template_prefix(text):
    """Drops a leading ``template <...>`` (balanced angle brackets)."""
    text = text.lstrip()
    if not text.startswith("template"):
        return text
    i = text.find("<")
    if i < 0:
        return text
    depth = 0
    for j in range(i, len(text)):
        if text[j] == "<":
            depth += 1
        elif text[j] == ">":
            depth -= 1
            if depth == 0:
                return text[j + 1 :].lstrip()
    return text


def _strip_access(text):
    return re.sub(r"^(?:\s*(?:public|private|protected)\s*:)+", "", text).strip()


def _split_declarators(text):
    """Top-level comma-separated parts of a declaration (template arguments and initialisers kept whole)."""
    parts, buf = [], []
    depth = 0  # (), {}, []
    angle = 0  # template arguments, only before an initialiser
    in_init = False
    i = 0
    while i < len(text):
        c = text[i]
        two = text[i : i + 2]
        if two in ("<<", ">>") and (in_init or angle == 0):
            buf.append(two)
            i += 2
            continue
        if c in "({[":
            depth += 1
        elif c in ")}]":
            depth -= 1
        elif c == "<" and not in_init and depth == 0:
            angle += 1
        elif c == ">" and not in_init and depth == 0 and angle > 0:
            angle -= 1
        elif c == "=" and depth == 0 and angle == 0:
            in_init = True
        elif c == "," and depth == 0 and angle == 0:
            parts.append("".join(buf))
            buf = []
            in_init = False
            i += 1
            continue
        buf.append(c)
        i += 1
    parts.append("".join(buf))
    return parts


def _declarator_name(part):
    """The declared name of one declarator: the last identifier before its initialiser or array bounds."""
    head = re.split(r"[={\[]", part, maxsplit=1)[0]
    names = _IDENT.findall(head)
    return names[-1] if names else None


def _function_name(text):
    """The name of a function declaration/definition head, or None if the statement is not a function."""
    depth = 0
    for i, c in enumerate(text):
        if c == "=" and depth == 0:
            return None  # an initialiser before any parameter list: a variable
        if c == "(" and depth == 0:
            names = _IDENT.findall(text[:i])
            if not names or "operator" in names:
                return None
            return names[-1]
        if c in "{[<":
            depth += 1
        elif c in "}]>":
            depth -= 1
    return None


def _statement_names(text, scope_kind):
    """Names a finished statement declares (enumerators, fields, functions)."""
    text = _strip_access(_strip_template_prefix(_strip_access(text)))
    if not text or _SKIP_STATEMENT.match(text):
        return []
    if scope_kind == "enum":
        m = _IDENT.match(text)
        return [m.group(0)] if m else []
    fn = _function_name(text)
    if fn is not None:
        return [fn]
    if "(" in text.split("=")[0] and scope_kind == "namespace":
        return []
    return [n for n in (_declarator_name(p) for p in _split_declarators(text)) if n]


def _split_line(line):
    """(code, trailing doc or None) of one line; ordinary // comments and string contents are dropped."""
    out, i, in_str = [], 0, None
    while i < len(line):
        c = line[i]
        if in_str:
            if c == "\\":
                i += 2
                continue
            if c == in_str:
                in_str = None
            i += 1
            continue
        if c in "\"'":
            in_str = c
            out.append(c + c)  # keep an empty literal so the statement stays well-formed
            i += 1
            continue
        if line.startswith("//", i):
            rest = line[i:]
            if rest.startswith("///<"):
                return "".join(out), rest[4:].strip()
            return "".join(out), None
        out.append(c)
        i += 1
    return "".join(out), None


def parse_header(text):
    """Docs of one header: an ordered dict key -> text, and the leading file comment ('' if none)."""
    lines = text.split("\n")
    file_doc = []
    for line in lines:
        s = line.strip()
        if s.startswith("//") and not s.startswith("///"):
            file_doc.append(s[2:][1:] if s[2:].startswith(" ") else s[2:])
        elif s.startswith("#pragma") or (not s and not file_doc):
            continue
        else:
            break

    docs = {}
    scopes = []  # (kind, key or None): kind in namespace | class | enum | block
    pending = []  # /// lines waiting for the next declaration
    buf = []  # code of the statement being read at a class/namespace/enum level
    buf_doc = None  # the /// doc captured when that statement started
    last = (None, -1)  # (keys of the last statement emitted, its line)
    block_head = []  # per open block: the statement text before its "{"

    def prefix():
        return ".".join(k for kind, k in scopes if kind in ("class", "enum") and k)

    def add(keys, doc):
        for k in keys:
            if doc and k not in docs:
                docs[k] = doc
            elif doc and k in docs and docs[k] != doc and not docs[k].endswith(doc):
                pass  # first declaration wins

    def emit(lineno):
        nonlocal buf, buf_doc, last, paren
        text_ = "".join(buf).strip()
        kind = scopes[-1][0] if scopes else "namespace"
        keys = []
        if text_:
            p = prefix()
            keys = [(p + "." + n) if p else n for n in _statement_names(text_, kind)]
            add(keys, buf_doc)
        last = (keys, lineno)
        buf, buf_doc, paren = [], None, 0

    paren = 0  # parenthesis depth of the statement being read
    in_block_comment = False
    for lineno, line in enumerate(lines):
        s = line.strip()
        if in_block_comment:
            if "*/" in s:
                in_block_comment = False
            continue
        if s.startswith("/*"):
            in_block_comment = "*/" not in s
            continue
        if s.startswith("#"):
            continue
        in_code_scope = not scopes or scopes[-1][0] != "block"
        if s.startswith("///<"):
            keys, _ = last
            extra = s[4:].strip()
            if in_code_scope and keys:
                for k in keys:
                    docs[k] = (docs.get(k, "") + "\n" + extra).strip()
            continue
        if s.startswith("///"):
            if in_code_scope:
                t = s[3:]
                pending.append(t[1:] if t.startswith(" ") else t)
            continue
        if not s:
            pending = [] if not buf else pending
            continue
        code, trail = _split_line(line)
        for c in code:
            top = scopes[-1][0] if scopes else "namespace"
            if top == "block":
                if c == "{":
                    scopes.append(("block", None))
                    block_head.append(None)
                elif c == "}":
                    scopes.pop()
                    head = block_head.pop()
                    now = scopes[-1][0] if scopes else "namespace"
                    if head is not None and now != "block" and _function_name(head) is not None:
                        emit(lineno)  # a function body ends its statement
                continue
            if not buf:
                if c.isspace():
                    continue  # statements start at their first character
                buf_doc = "\n".join(pending).strip() or None
                pending = []
            if c in "()":
                paren += 1 if c == "(" else -1
            if paren > 0:
                buf.append(c)  # default arguments ("= {}") are not scopes
                continue
            if c == "{":
                head = "".join(buf).strip()
                head_clean = _strip_access(_strip_template_prefix(_strip_access(head)))
                m_class = _CLASS_HEAD.search(head_clean)
                m_enum = _ENUM_HEAD.search(head_clean)
                if _NAMESPACE_HEAD.search(head_clean) and not m_class:
                    scopes.append(("namespace", None))
                    buf, buf_doc = [], None
                elif m_enum and "=" not in head_clean:
                    name = m_enum.group(1)
                    p = prefix()
                    key = ((p + "." + name) if p else name) if name else None
                    if key:
                        add([key], buf_doc)
                    scopes.append(("enum", name))
                    last = ([key] if key else [], lineno)
                    buf, buf_doc = [], None
                elif m_class and "=" not in head_clean and "(" not in head_clean:
                    name = m_class.group(1)
                    p = prefix()
                    key = (p + "." + name) if p else name
                    add([key], buf_doc)
                    scopes.append(("class", name))
                    last = ([key], lineno)
                    buf, buf_doc = [], None
                else:
                    scopes.append(("block", None))
                    block_head.append(head)
                    buf.append("{...}")
                continue
            if c == "}":
                if top == "enum" and "".join(buf).strip():
                    emit(lineno)
                buf, buf_doc = [], None
                if scopes:
                    scopes.pop()
                continue
            if c == ":" and "".join(buf).strip() in ("public", "private", "protected"):
                buf, buf_doc = [], None  # an access specifier is not a statement
                continue
            if c == ";" or (c == "," and top == "enum"):
                emit(lineno)
                continue
            buf.append(c)
        if trail is not None and not (scopes and scopes[-1][0] == "block"):
            keys, at = last
            if buf and "".join(buf).strip():
                # a statement still open on this line: its doc (e.g. "int k =" continued below)
                buf_doc = ((buf_doc or "") + "\n" + trail).strip()
            elif keys and at == lineno:
                for k in keys:
                    docs[k] = (docs.get(k, "") + "\n" + trail).strip() if k in docs else trail
    return docs, "\n".join(file_doc).strip()


def _cpp_string(text):
    delim = "perch2doc"
    while ")" + delim + '"' in text:
        delim += "_"
    return 'R"' + delim + "(" + text + ")" + delim + '"'


def write_header(entries, out_path):
    lines = [
        "// Generated by python/tools/header_docs.py from perch2's headers at build time: do not edit.",
        "#pragma once",
        "",
        "namespace perch2_py {",
        "struct DocEntry {",
        "  const char* key;",
        "  const char* text;",
        "};",
        "inline constexpr DocEntry kDocEntries[] = {",
    ]
    for key, text in entries.items():
        lines.append("    {" + _cpp_string(key) + ", " + _cpp_string(text) + "},")
    lines += ["};", "}  // namespace perch2_py", ""]
    content = "\n".join(lines)
    if os.path.exists(out_path):
        with open(out_path, encoding="utf-8") as f:
            if f.read() == content:
                return  # unchanged: keep the timestamp (no rebuild of the bindings)
    with open(out_path, "w", encoding="utf-8") as f:
        f.write(content)


def collect(headers, root):
    entries = {}
    for h in headers:
        with open(h, encoding="utf-8") as f:
            docs, file_doc = parse_header(f.read())
        if file_doc:
            rel = os.path.relpath(h, root) if root else os.path.basename(h)
            entries.setdefault("file:" + rel.replace(os.sep, "/"), file_doc)
        for k, v in docs.items():
            entries.setdefault(k, v)
    return entries


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", required=True, help="C++ header to write")
    ap.add_argument("--root", action="append", default=[], help="folder the file: keys are relative to")
    ap.add_argument("headers", nargs="+")
    a = ap.parse_args(argv)
    entries = {}
    for h in a.headers:
        root = next((r for r in a.root if os.path.abspath(h).startswith(os.path.abspath(r) + os.sep)), None)
        for k, v in collect([h], root).items():
            entries.setdefault(k, v)
    write_header(entries, a.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
