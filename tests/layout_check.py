#!/usr/bin/env python3
"""layout_check.py — the layering rules the compiler cannot check (docs/development.md, the
top of CMakeLists.txt), read from the source tree itself:

  1. Only render/gpu/ talks to Vulkan: no file outside it calls a vk* function or includes
     <vulkan/...>.
  2. A folder includes only the headers of the folders it may see:
       cli     -> cli, server/include, io, offline, render/include
       server  -> server (with server/include), io, offline, render/include
       io      -> io, render/include
       offline -> offline, render/include
       render  -> render, render/gpu, render/include, shaders
       shaders -> shaders, render/include
       tests   -> everything
       bench   -> bench, io, offline, render (its internals, as the GPU tests), render/gpu,
                  render/include, shaders: the benchmarks, never the cli or the server
     A quoted include is resolved the way the compiler does it: beside the including file
     first, then anywhere in the tree (every header name is unique, so the folder is known).
     A name found nowhere in the tree (a generated *_spv.h, a third-party header) is listed
     and not checked. System headers (<...>) are ignored, except Vulkan's.
  3. No include cycle between folders (render/gpu and render/include counting as folders of
     their own, so that a private render header included back from render/gpu is one).
  4. No "../" in any include: a header is found through its folder's include directory.
  5. Every uniform and push-constant block of a shader (shaders/*.comp, *.glsl) declares its
     member as an array of one, read at NS_OPAQUE_ZERO (shaders/shared.h): lavapipe 22.3
     compiles a kernel again at every bind, and keeps every copy, when it reads such a block
     at a constant offset (docs/rendering.md, "lavapipe's uniform inlining").

Every violation is printed with its file and line; the exit status is 1 if there was any,
or if the tree did not look like nscatter's source at all (a check that read nothing would
pass everything). The tree is the first argument, else $NSCATTER_SOURCE_DIR (set by ctest),
else this file's parent folder.
"""
import os
import re
import sys

# The folders whose includes are checked, finest first: a file belongs to the first one its
# path lies in.
UNITS = ["render/gpu", "render/include", "server/include", "cli", "server", "io", "offline",
         "render", "shaders", "tests", "bench"]

# What each layer (top-level folder, all of its subfolders) may include. None: anything.
ALLOWED = {
    "cli": {"cli", "server/include", "io", "offline", "render/include"},
    "server": {"server", "server/include", "io", "offline", "render/include"},
    "io": {"io", "render/include"},
    "offline": {"offline", "render/include"},
    "render": {"render", "render/gpu", "render/include", "shaders"},
    "shaders": {"shaders", "render/include"},
    "tests": None,
    "bench": {"bench", "io", "offline", "render", "render/gpu", "render/include", "shaders"},
}

SOURCE_EXTENSIONS = (".c", ".h", ".cpp", ".cc", ".hpp", ".hh", ".comp", ".glsl", ".c.in",
                     ".h.in")
INCLUDE = re.compile(r'^[ \t]*#[ \t]*include[ \t]*([<"])([^>"\n]*)[>"]', re.M)
VULKAN_CALL = re.compile(r"\b(vk[A-Z]\w*)\s*\(")
UNIFORM_BLOCK = re.compile(r"\buniform\s+(\w+)\s*\{([^}]*)\}")
ARRAY_OF_ONE = re.compile(r"^\s*\w+\s+\w+\s*\[\s*1\s*\]\s*;\s*$")


def strip(text):
    """Returns (text without comments, text without comments and string/char literals), each
    the same length as text with every newline kept, so that offsets give line numbers."""
    code, bare = [], []
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            code.append(" " * (j - i))
            bare.append(" " * (j - i))
            i = j
        elif text.startswith("/*", i):
            j = text.find("*/", i + 2)
            j = n if j < 0 else j + 2
            blank = re.sub(r"[^\n]", " ", text[i:j])
            code.append(blank)
            bare.append(blank)
            i = j
        elif c in "\"'":
            j = i + 1
            while j < n and text[j] != c and text[j] != "\n":
                j += 2 if text[j] == "\\" else 1
            j = min(j + 1, n)
            code.append(text[i:j])
            bare.append(c + re.sub(r"[^\n]", " ", text[i + 1:j - 1]) + (c if j - i > 1 else ""))
            i = j
        else:
            code.append(c)
            bare.append(c)
            i += 1
    return "".join(code), "".join(bare)


def line_of(text, offset):
    return text.count("\n", 0, offset) + 1


def unit_of(rel):
    """The folder (one of UNITS) that the file at rel lies in, or None."""
    for unit in UNITS:
        if rel.startswith(unit + "/"):
            return unit
    return None


def layer_of(unit):
    return unit.split("/")[0] if unit else None


def source_files(root):
    """Every source file of the tree, as paths relative to root; build trees (a folder with a
    CMakeCache.txt), hidden folders and node_modules are left out."""
    found = []
    for folder, dirs, files in os.walk(root):
        dirs[:] = sorted(d for d in dirs if not d.startswith(".") and d != "node_modules"
                         and not os.path.exists(os.path.join(folder, d, "CMakeCache.txt")))
        for name in sorted(files):
            if name.endswith(SOURCE_EXTENSIONS):
                found.append(os.path.relpath(os.path.join(folder, name), root).replace(os.sep, "/"))
    return found


def resolve(rel, name, files_by_suffix, all_files):
    """The tree file a quoted include of `name` in file rel names, or a list of candidates
    when several could (ambiguous), or None when it is not in the tree."""
    beside = os.path.normpath(os.path.join(os.path.dirname(rel), name)).replace(os.sep, "/")
    if beside in all_files:
        return beside
    candidates = files_by_suffix.get(name.split("/")[-1], [])
    candidates = [f for f in candidates if f == name or f.endswith("/" + name)]
    if len(candidates) == 1:
        return candidates[0]
    return candidates or None


def strongly_connected(graph):
    """Tarjan: the strongly connected components of graph (node -> set of nodes)."""
    index, low, stack, on_stack, components = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            components.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return components


def cycle_through(graph, nodes):
    """One cycle inside the strongly connected `nodes`, as a list of folders that starts and
    ends at the same one: breadth first from the first node until an edge leads back to it."""
    start = nodes[0]
    previous, queue = {start: None}, [start]
    while queue:
        v = queue.pop(0)
        for w in sorted(graph.get(v, ())):
            if w == start:
                path = [v]
                while previous[path[-1]] is not None:
                    path.append(previous[path[-1]])
                return path[::-1] + [start]
            if w in nodes and w not in previous:
                previous[w] = v
                queue.append(w)
    return nodes + [nodes[0]]


def main():
    if len(sys.argv) > 1:
        root = sys.argv[1]
    else:
        root = os.environ.get("NSCATTER_SOURCE_DIR") or os.path.dirname(
            os.path.dirname(os.path.abspath(__file__)))
    root = os.path.realpath(root)
    files = source_files(root)
    all_files = set(files)
    files_by_suffix = {}
    for f in files:
        files_by_suffix.setdefault(f.split("/")[-1], []).append(f)

    problems = []  # (file, line, message)
    edges = {}  # unit -> included unit -> first (file, line, include text, header)
    unresolved = {}  # include name -> first (file, line)
    include_count = 0
    for rel in files:
        with open(os.path.join(root, rel), encoding="utf-8", errors="replace") as f:
            text = f.read()
        code, bare = strip(text)
        unit = unit_of(rel)
        layer = layer_of(unit)

        if unit != "render/gpu":
            for m in VULKAN_CALL.finditer(bare):
                problems.append((rel, line_of(bare, m.start()),
                                 f"calls the Vulkan function {m.group(1)}(); only render/gpu/ "
                                 "may call Vulkan"))

        if rel.endswith((".comp", ".glsl")):
            for m in UNIFORM_BLOCK.finditer(bare):
                members = [x for x in m.group(2).split(";") if x.strip()]
                if len(members) != 1 or not ARRAY_OF_ONE.match(members[0] + ";"):
                    problems.append((rel, line_of(bare, m.start()),
                                     f"uniform block {m.group(1)} is not one member declared as "
                                     "an array of one (read it at NS_OPAQUE_ZERO, shaders/shared.h"
                                     "; lavapipe recompiles and keeps a kernel that reads a "
                                     "block at a constant offset)"))

        for m in INCLUDE.finditer(code):
            include_count += 1
            line = line_of(code, m.start())
            delimiter, name = m.group(1), m.group(2).strip()
            shown = f"<{name}>" if delimiter == "<" else f'"{name}"'
            if "../" in name or name.startswith(".."):
                problems.append((rel, line, f"relative include {shown}: include a header by its "
                                 "name, through its folder's include directory"))
            if name.startswith("vulkan/") and unit != "render/gpu":
                problems.append((rel, line, f"includes {shown}; only render/gpu/ may include "
                                 "Vulkan's headers"))
            if delimiter == "<" or unit is None:
                continue
            header = resolve(rel, name, files_by_suffix, all_files)
            if header is None:
                unresolved.setdefault(name, (rel, line))
                continue
            allowed = ALLOWED.get(layer)
            if isinstance(header, list):
                # Several tree files could be meant: the compiler takes whichever its include
                # path reaches, so the include is fine if one of them is in an allowed folder.
                fine = [h for h in header if allowed is None or unit_of(h) in allowed]
                if not fine:
                    problems.append((rel, line, f"includes {shown}, which could be "
                                     f"{' or '.join(header)}; {layer}/ may include only "
                                     f"{', '.join(f + '/' for f in sorted(allowed))}"))
                    continue
                header = fine[0]
            target = unit_of(header)
            if target is None:
                problems.append((rel, line, f"includes {shown} ({header}), which lies in no "
                                 "library folder"))
                continue
            if allowed is not None and target not in allowed:
                problems.append((rel, line, f"includes {shown} ({header}): {layer}/ may include "
                                 f"only {', '.join(f + '/' for f in sorted(allowed))}"))
            if target != unit:
                edges.setdefault(unit, {}).setdefault(target, (rel, line, shown, header))

    graph = {u: set(t) for u, t in edges.items()}
    for component in strongly_connected(graph):
        if len(component) < 2:
            continue
        cycle = cycle_through(graph, component)
        rel, line, shown, header = edges[cycle[0]][cycle[1]]
        detail = "\n".join(
            f"      {a} -> {b}: {edges[a][b][0]}:{edges[a][b][1]} includes {edges[a][b][2]} "
            f"({edges[a][b][3]})" for a, b in zip(cycle, cycle[1:]))
        problems.append((rel, line, f"include cycle between folders: {' -> '.join(cycle)}\n"
                         + detail))

    print(f"layout_check: {root}: {len(files)} source files, {include_count} includes")
    if len(files) == 0 or not os.path.isdir(os.path.join(root, "render", "gpu")):
        print("FAIL: this is not nscatter's source tree (no source files, or no render/gpu/): "
              "set NSCATTER_SOURCE_DIR")
        return 1
    print("folders and the folders they include:")
    for unit in UNITS:
        if unit in edges:
            print(f"  {unit:15} -> {', '.join(sorted(edges[unit]))}")
    if unresolved:
        print("not in the source tree (generated or third-party), not checked: "
              + ", ".join(f'"{n}" ({f}:{line})' for n, (f, line) in sorted(unresolved.items())))
    for rel, line, message in sorted(problems):
        print(f"FAIL {rel}:{line}: {message}")
    if problems:
        print(f"{len(problems)} layout violation{'s' if len(problems) != 1 else ''}")
        return 1
    print("layout ok: Vulkan only in render/gpu/, every include within its folder's reach, "
          "no cycle between folders, no relative include, every shader block an array of one")
    return 0


if __name__ == "__main__":
    sys.exit(main())
