"""``python -m hil.config --write``: the schema document config/SCHEMA.md regenerated in place, its
prose kept; without ``--write`` it goes to stdout (redirecting that into config/SCHEMA.md itself
would empty the prose before it is read)."""
import sys

from hil.config.docs import schema_markdown
from hil.config.loader import examples_dir

path = examples_dir() / "SCHEMA.md"
text = path.read_text(encoding="utf-8").split("| key |")[0] + schema_markdown()
if sys.argv[1:] == ["--write"]:
    path.write_text(text, encoding="utf-8")       # read in full above: nothing is lost
elif sys.argv[1:]:
    sys.exit(f"python -m hil.config: unknown arguments {' '.join(sys.argv[1:])} (expected --write or none)")
else:
    sys.stdout.write(text)
