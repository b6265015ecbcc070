#!/usr/bin/env python3
"""Import circles between the modules of each crate of the workspace.

Usage: .ci/circles.py [CRATE_DIR ...]   (default: every crates/*)

A module uses another when its file names it by path anywhere, in a `use`
or in code: `crate::a::b::f()`, `super::x::Y`, `use super::{a, b}`, or a
child module by its bare name (`bus::open()` in `can/mod.rs`). A path that
ends at an item re-exported by a module (`pub use child::Item`) counts as a
use of the module that defines it, so that a facade (`lib.rs`, a `mod.rs`
of re-exports) makes no circle of its own. Every strongly connected
component of two or more modules is printed with the uses that close it;
the exit status is 1 if there is one. A module's use of its own ancestors
(`super::Config` defined in the parent's `mod.rs`) is not counted: a parent
that uses its children and children that use what their parent defines is a
module tree, not a circle.

Why our own: cargo-modules (the tool the issue suggests) has an `--acyclic`
check, but over its graph of every item (a struct and its own `new` make a
"circle" there), and its "uses" edges come from `use` declarations and
signatures only, not from paths in function bodies: it misses the circle of
`can/bus.rs`, whose `open` calls each transport that uses its trait. This
reads the source instead, which Rust makes simple enough: a module is a file
(inline `mod name { .. }` blocks count as part of their file's module).
"""
import os
import re
import sys

PATH = re.compile(r"\b(crate|super|self)((?:::[A-Za-z_][A-Za-z0-9_]*)+)")
USE = re.compile(r"\b(?:pub(?:\([^)]*\))?\s+)?use\s+([^;]+);", re.S)
MOD = re.compile(r"^\s*(?:pub(?:\([^)]*\))?\s+)?mod\s+([A-Za-z_][A-Za-z0-9_]*)\s*;", re.M)
PATH_ATTR = re.compile(r'#\[path\s*=\s*"([^"]+)"\]\s*(?:pub(?:\([^)]*\))?\s+)?mod\s+([A-Za-z_]\w*)\s*;')
BARE = re.compile(r"(?<![:\w])([a-z_][a-z0-9_]*)::[A-Za-z_]")


def strip(text):
    """The source without comments, strings and char literals."""
    out, i, n = [], 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            i = n if j < 0 else j
        elif text.startswith("/*", i):
            depth, i = 1, i + 2
            while i < n and depth:
                if text.startswith("/*", i):
                    depth, i = depth + 1, i + 2
                elif text.startswith("*/", i):
                    depth, i = depth - 1, i + 2
                else:
                    i += 1
        elif c == "r" and re.match(r'r#*"', text[i:i + 10]) and (i == 0 or not (text[i - 1].isalnum() or text[i - 1] == "_")):
            hashes = len(re.match(r'r(#*)"', text[i:]).group(1))
            end = text.find('"' + "#" * hashes, i + 2 + hashes)
            i = n if end < 0 else end + 1 + hashes
            out.append('""')
        elif c == '"':
            i += 1
            while i < n and text[i] != '"':
                i += 2 if text[i] == "\\" else 1
            i += 1
            out.append('""')
        elif c == "'" and re.match(r"'(\\.|[^\\'])'", text[i:i + 4]):
            i += len(re.match(r"'(\\.|[^\\'])'", text[i:i + 4]).group(0))
        else:
            out.append(c)
            i += 1
    return "".join(out)


def expand_use(tree):
    """`a::{b, c::{d, e as f}, self}` -> [a::b, a::c::d, a::c::e, a]."""
    tree = re.sub(r"\s+", "", re.sub(r"\s+as\s+\w+", "", tree))

    def walk(prefix, text):
        paths, depth, start, parts = [], 0, 0, []
        for k, ch in enumerate(text):
            if ch == "{":
                depth += 1
            elif ch == "}":
                depth -= 1
            elif ch == "," and depth == 0:
                parts.append(text[start:k])
                start = k + 1
        parts.append(text[start:])
        for part in parts:
            if not part:
                continue
            brace = part.find("{")
            if brace >= 0 and part.endswith("}"):
                paths += walk(prefix + part[:brace], part[brace + 1:-1])
            elif part == "self":
                paths.append(prefix.rstrip(":"))
            else:
                paths.append(prefix + part)
        return paths

    return walk("", tree)


class Crate:
    def __init__(self, root_file):
        self.modules = {}  # module path (tuple) -> stripped source
        self.exports = {}  # module -> {name: module path of the item's definer}
        self.load(root_file, ())

    def load(self, path, module):
        try:
            text = strip(open(path, encoding="utf-8").read())
        except OSError:
            return
        self.modules[module] = text
        here = os.path.dirname(path)
        own_dir = here if os.path.basename(path) in ("lib.rs", "main.rs", "mod.rs") else os.path.join(here, os.path.basename(path)[:-3])
        explicit = {name: target for target, name in PATH_ATTR.findall(text)}
        for name in MOD.findall(text):
            if name in explicit:
                child = os.path.normpath(os.path.join(here, explicit[name]))
            else:
                child = os.path.join(own_dir, name + ".rs")
                if not os.path.exists(child):
                    child = os.path.join(own_dir, name, "mod.rs")
            self.load(child, module + (name,))

    def children(self, module):
        return {m[-1] for m in self.modules if len(m) == len(module) + 1 and m[:len(module)] == module}

    def absolute(self, module, path):
        """`path` (a list of segments as written in `module`) from the crate root."""
        head, rest = path[0], path[1:]
        if head == "crate":
            base = ()
        elif head == "self":
            base = module
        elif head == "super":
            base = module[:-1]
            while rest and rest[0] == "super":
                base, rest = base[:-1], rest[1:]
        elif head in self.children(module):
            base, rest = module, path
        else:
            return None
        return list(base) + list(rest)

    def target(self, segments, seen=0):
        """The module that defines what `segments` (from the root) names."""
        segments = list(segments)
        module = ()
        for k, name in enumerate(segments):
            if module + (name,) in self.modules:
                module = module + (name,)
                continue
            # An item of `module`, or one it re-exports.
            exported = self.reexports(module).get(name)
            if exported is not None and seen < 16:
                return self.target(list(exported) + segments[k + 1:], seen + 1)
            return module
        return module

    def reexports(self, module):
        if module not in self.exports:
            self.exports[module] = {}
            for tree in USE.findall(self.modules.get(module, "")):
                for path in expand_use(tree):
                    segments = [s for s in path.split("::") if s]
                    if not segments or segments[-1] == "*":
                        continue
                    absolute = self.absolute(module, segments)
                    if absolute:
                        self.exports[module][absolute[-1]] = absolute
        return self.exports[module]

    def uses(self):
        edges = {}
        for module, text in self.modules.items():
            found = set()
            for tree in USE.findall(text):
                for path in expand_use(tree):
                    segments = [s for s in path.split("::") if s and s != "*"]
                    absolute = segments and self.absolute(module, segments)
                    if absolute:
                        found.add(self.target(absolute))
            for head, tail in PATH.findall(text):
                absolute = self.absolute(module, [head] + tail.strip(":").split("::"))
                if absolute:
                    found.add(self.target(absolute))
            children = self.children(module)
            for name in BARE.findall(text):
                if name in children:
                    found.add(module + (name,))
            found.discard(module)
            # A module using what its ancestors define (a constant of its
            # `mod.rs`, the crate's error type) is how a module tree is
            # meant to be used, and no circle: only uses of siblings,
            # cousins and descendants count.
            edges[module] = {m for m in found if m in self.modules and m != module[: len(m)]}
        return edges


def components(nodes, edges):
    index, low, on_stack, stack, found, counter = {}, {}, set(), [], [], [0]
    for start in sorted(nodes):
        if start in index:
            continue
        index[start] = low[start] = counter[0]
        counter[0] += 1
        stack.append(start)
        on_stack.add(start)
        work = [(start, iter(sorted(edges.get(start, ()))))]
        while work:
            node, children = work[-1]
            advanced = False
            for child in children:
                if child not in index:
                    index[child] = low[child] = counter[0]
                    counter[0] += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(edges.get(child, ())))))
                    advanced = True
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            if advanced:
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


def main():
    crates = sys.argv[1:] or sorted(os.path.join("crates", d) for d in os.listdir("crates"))
    circles = 0
    for crate in crates:
        for root in ("src/lib.rs", "src/main.rs"):
            path = os.path.join(crate, root)
            if not os.path.exists(path):
                continue
            parsed = Crate(path)
            edges = parsed.uses()
            name = os.path.basename(crate) + ("" if root == "src/lib.rs" else " (bin)")
            for component in components(parsed.modules, edges):
                circles += 1
                members = set(component)
                show = lambda m: "::".join(m) or "(root)"
                print(f"{name}: circle: " + " <-> ".join(show(m) for m in component))
                for source in component:
                    for target in sorted(edges[source] & members):
                        print(f"    {show(source)} uses {show(target)}")
    print(f"circles: {circles}")
    sys.exit(1 if circles else 0)


if __name__ == "__main__":
    main()
