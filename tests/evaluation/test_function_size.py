"""The evaluation stays readable: no function of ushape/evaluation is longer than 60 lines."""

import ast
from pathlib import Path

EVALUATION = Path(__file__).resolve().parents[2] / "ushape" / "evaluation"
MAX_LINES = 60


def long_functions(folder: Path, limit: int = MAX_LINES) -> list[str]:
    """'path:line name (n lines)' for every function or method over `limit` lines, decorators excluded."""
    found = []
    for path in sorted(folder.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                lines = node.end_lineno - node.lineno + 1
                if lines > limit:
                    found.append(f"{path.name}:{node.lineno} {node.name} ({lines} lines)")
    return found


def test_no_evaluation_function_is_over_60_lines():
    assert not long_functions(EVALUATION), "split these: " + ", ".join(long_functions(EVALUATION))


def test_the_check_counts_a_long_function(tmp_path):
    body = "\n".join(f"    x{i} = {i}" for i in range(60))
    (tmp_path / "m.py").write_text(f"def short():\n    pass\n\n\ndef long():\n{body}\n")
    assert long_functions(tmp_path) == ["m.py:5 long (61 lines)"]
