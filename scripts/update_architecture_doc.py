"""Maintainers: rewrite the generated blocks of docs/architecture.md (import graph and table) from the tree.

    python scripts/update_architecture_doc.py

tests/test_architecture.py checks that the committed blocks match what this writes.
"""
from __future__ import annotations

import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))

import import_graph as graph  # noqa: E402


def main() -> None:
    doc = ROOT / "docs" / "architecture.md"
    text = doc.read_text(encoding="utf-8")
    packages = graph.package_graph()
    for name, lang, body in (
            ("import-graph", "mermaid", graph.render_mermaid(graph.transitive_reduction(packages))),
            ("import-table", "text", graph.render_text(packages))):
        pattern = rf"(<!-- {name}:begin -->\n```{lang}\n)(.*?)(```\n<!-- {name}:end -->)"
        if not re.search(pattern, text, re.S):
            raise SystemExit(f"docs/architecture.md lacks the generated block {name}")
        text = re.sub(pattern, lambda m: m.group(1) + body.strip() + "\n" + m.group(3), text, flags=re.S)
    tmp = doc.with_suffix(".md.tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(doc)
    print(f"updated {doc.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
