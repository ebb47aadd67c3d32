"""``python -m hil.config > config/SCHEMA.md``: the schema document, its prose kept."""
import sys

from hil.config.docs import schema_markdown
from hil.config.loader import examples_dir

text = (examples_dir() / "SCHEMA.md").read_text(encoding="utf-8")
sys.stdout.write(text.split("| key |")[0] + schema_markdown())
