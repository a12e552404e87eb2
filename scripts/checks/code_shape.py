#!/usr/bin/python3
"""The layout rules of docs/architecture.md, checked on the sources (CTest code_shape).

    /usr/bin/python3 scripts/checks/code_shape.py [--lengths]

1. The programs go through the public library: no file under tools/ includes a header of model/
   or engine/, except the op benchmark (tools/spar_bench/bench_cases.*, op_bench.*, bench_peer.*),
   which includes the one internal header engine/internal_ops.h.
2. Vulkan stays in the engine: no public header (include/spar/) includes vulkan.h, and no file
   outside engine/, api/ and tests includes engine/vk_result.h.
3. Every public header's implementation is in api/: no source file outside api/ defines a
   method of a class or struct the public headers export (SPAR_API).
4. No function in model/, tools/ or api/ is longer than 120 lines (PYBIND11_MODULE excepted).
--lengths prints every function over 60 lines with its length. Exit 1 and one line per finding.
"""
import glob
import os
import re
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
MAX_LINES = 120
OP_BENCHMARK = {"tools/spar_bench/" + f for f in
                ["bench_cases.h", "bench_cases.cpp", "op_bench.h", "op_bench.cpp", "bench_peer.h", "bench_peer.cpp"]}
INCLUDE = re.compile(r'^\s*#\s*include\s*[<"]([^">]+)[">]', re.M)


def sources(*folders, exts=(".h", ".cpp")):
    for folder in folders:
        for path in sorted(glob.glob(os.path.join(ROOT, folder, "**", "*"), recursive=True)):
            if path.endswith(exts):
                yield os.path.relpath(path, ROOT)


def read(rel):
    return open(os.path.join(ROOT, rel), encoding="utf-8").read()


def includes(rel):
    return INCLUDE.findall(read(rel))


def strip_code(text):
    """The text with comments, string and character literals blanked (newlines kept)."""
    out, i, n = [], 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            out.append(" " * (j - i))
            i = j
        elif text.startswith("/*", i):
            j = text.find("*/", i + 2)
            j = n if j < 0 else j + 2
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
        elif text.startswith('R"', i) and (i == 0 or not (text[i - 1].isalnum() or text[i - 1] == "_")):
            m = re.match(r'R"([^(]*)\(', text[i:])
            end = text.find(")" + m.group(1) + '"', i) if m else -1
            j = n if end < 0 else end + len(m.group(1)) + 2
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
        elif c in "\"'":
            j = i + 1
            while j < n and text[j] != c:
                j += 2 if text[j] == "\\" else 1
            out.append(c + " " * (j - i - 1) + c)
            i = j + 1
        else:
            out.append(c)
            i += 1
    return "".join(out)


def functions(rel):
    """(name, first line, lines) of every function body at namespace or class level."""
    code = strip_code(read(rel))
    found, depth_kinds, i, start = [], [], 0, 0
    for i, c in enumerate(code):
        if c in ";}":
            if c == "}" and depth_kinds:
                kind, line0, name = depth_kinds.pop()
                if kind == "function":
                    found.append((name, line0, code.count("\n", 0, i) - line0 + 2))
            start = i + 1
        elif c == "{":
            head = code[start:i]
            inside_function = any(k == "function" or k == "other" for k, _, _ in depth_kinds)
            kind = "other"
            if not inside_function:
                if re.search(r"\b(namespace|class|struct|union|enum)\b[^()]*$", head) or re.search(r"=\s*$", head):
                    kind = "scope"
                elif ")" in head:
                    kind = "function"
            stripped = head.lstrip()
            line0 = code.count("\n", 0, start + (len(head) - len(stripped)))
            name_match = re.search(r"([A-Za-z_][\w:~]*)\s*\([^()]*(\([^()]*\)[^()]*)*\)[^()]*$", head)
            depth_kinds.append((kind, line0, name_match.group(1) if name_match else head.strip()[:40]))
            start = i + 1
    return found


def public_classes():
    """"Class::" of every class and struct the public headers export (SPAR_API)."""
    names = set()
    for rel in sources("include/spar", exts=(".h",)):
        for cls in re.finditer(r"\b(?:class|struct)\s+SPAR_API\s+(\w+)", strip_code(read(rel))):
            names.add(cls.group(1) + "::")
    return names


def main():
    findings, show = [], "--lengths" in sys.argv
    for rel in sources("tools"):
        for inc in includes(rel):
            internal = inc.startswith(("model/", "engine/"))
            if internal and not (rel in OP_BENCHMARK and inc == "engine/internal_ops.h"):
                findings.append(f"{rel}: includes {inc} (the programs go through include/spar/)")
    for rel in sources("include/spar", exts=(".h",)):
        if any("vulkan" in inc for inc in includes(rel)):
            findings.append(f"{rel}: a public header includes Vulkan")
    for rel in sources("text", "imaging", "formats", "model", "tools", "selftest", "python"):
        if "engine/vk_result.h" in includes(rel):
            findings.append(f"{rel}: includes engine/vk_result.h (only the engine's own Vulkan calls need it)")
    classes = public_classes()
    for rel in sources("engine", "model", "text", "imaging", "formats", "selftest", "tools", exts=(".cpp",)):
        for name, line, _ in functions(rel):
            if "::" in name and name.split("::")[-2] + "::" in classes:
                findings.append(f"{rel}:{line + 1}: {name} implements a public header outside api/")
    for rel in sources("model", "tools", "api", "python"):
        for name, line, length in functions(rel):
            if show and length > 60:
                print(f"{length:4d} {rel}:{line + 1} {name}")
            if length > MAX_LINES and not name.startswith("PYBIND11_MODULE") and not rel.startswith("python/"):
                findings.append(f"{rel}:{line + 1}: {name} is {length} lines (at most {MAX_LINES})")
    for f in dict.fromkeys(findings):
        print(f)
    if not show:
        print(f"code_shape: {len(findings)} finding(s)")
    return 1 if findings else 0


if __name__ == "__main__":
    sys.exit(main())
