"""Print the commands of a Markdown file's first fenced block, one a line, as written (blank
lines and comment lines left out): what CI runs as a newcomer would."""

import sys
from pathlib import Path


def first_block(text: str) -> list[str]:
    lines, inside = [], False
    for line in text.splitlines():
        if line.lstrip().startswith("```"):
            if inside:
                return lines
            inside = True
            continue
        if inside and line.strip() and not line.lstrip().startswith("#"):
            lines.append(line.strip())
    return lines if inside else []


if __name__ == "__main__":
    print("\n".join(first_block(Path(sys.argv[1]).read_text(encoding="utf-8"))))
