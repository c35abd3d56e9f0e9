"""The kernels' module constants (column and stream indices) are each bound once: a second
binding of a name would silently move an earlier stage onto another stage's columns."""
import ast
from collections import Counter
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "rawaug"


def _bound_names(path: Path) -> Counter:
    names = Counter()
    for node in ast.parse(path.read_text()).body:
        targets = node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(node, ast.AnnAssign) else []
        for target in targets:
            for leaf in ast.walk(target):
                if isinstance(leaf, ast.Name):
                    names[leaf.id] += 1
    return names


@pytest.mark.parametrize("kernel", ["cpu/fused.py", "gpu/fused.py"])
def test_kernel_module_constants_are_bound_once(kernel):
    names = _bound_names(ROOT / kernel)
    assert len(names) > 50, len(names)  # the module's constants were read
    twice = sorted(name for name, n in names.items() if n > 1)
    assert not twice, twice
