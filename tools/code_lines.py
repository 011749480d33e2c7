"""Code lines of a package folder without docstrings, comments, blank lines and teaching text.

    python tools/code_lines.py [FOLDER]        # default navlab/filters

Prints the count per file and the total (issue 23 measures navlab/filters by it).
"""

import ast
import pathlib
import sys

root = pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else "navlab/filters")
total = 0
for f in sorted(root.rglob("*.py")):
    src = f.read_text()
    tree = ast.parse(src)
    skip = set()
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and body:
            d = body[0]
            if (
                isinstance(d, ast.Expr)
                and isinstance(d.value, ast.Constant)
                and isinstance(d.value.value, str)
            ):
                skip.update(range(d.lineno, d.end_lineno + 1))
        if isinstance(node, ast.Call) and getattr(node.func, "id", "") == "Teaching":
            skip.update(range(node.lineno, node.end_lineno + 1))
        if isinstance(node, ast.Assign) and any(getattr(t, "id", "") == "teaching" for t in node.targets):
            skip.update(range(node.lineno, node.end_lineno + 1))
    n = 0
    for i, line in enumerate(src.splitlines(), 1):
        s = line.strip()
        if not s or s.startswith("#") or i in skip:
            continue
        n += 1
    total += n
    print(f"{n:6d} {f}")
print(f"{total:6d} total")
