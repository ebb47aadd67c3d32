"""One default per key (issue 48): where the code reads a key with a default of its own,
``cfg.get("key", default)``, that default is the schema's (hil.config.field_for), so that a
config built without validation and one validated read alike, and the reference pages say what
the code does. ``runtime.start_position`` read ``control.position_feedback`` as "motor" by
default where the schema says "table"."""
import ast
import re
from pathlib import Path

from hil.config import field_for

ROOT = Path(__file__).resolve().parents[1]
READ = re.compile(r'cfg\.get\("([a-z_.0-9]+)",\s*([^()]+?)\)')


def reads_with_defaults():
    for path in sorted([*(ROOT / "hil").rglob("*.py"), *(ROOT / "drivers").rglob("*.py")]):
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            for key, literal in READ.findall(line):
                try:
                    value = ast.literal_eval(literal)
                except (ValueError, SyntaxError):
                    continue            # a name (a module's constant): not a literal default
                yield f"{path.relative_to(ROOT)}:{n}", key, value


def test_every_default_in_the_code_is_the_schemas():
    found = list(reads_with_defaults())
    assert len(found) > 30
    differ = []
    for where, key, value in found:
        f = field_for(key)
        if f is not None and f.default is not None and f.default != value:
            differ.append(f"{where}: {key} read with default {value!r}, the schema's is {f.default!r}")
    assert not differ, "\n".join(differ)
