"""A readings page rewritten part by part: a run of some parts replaces their sections and keeps the others'."""

from __future__ import annotations


def _sections(text: str) -> tuple[list[str], dict]:
    """Split a page into its unmarked lines and {part: lines between its markers}."""
    legacy, marked, cur = [], {}, None
    for line in text.splitlines():
        if line.startswith("<!-- part: "):
            cur = line[len("<!-- part: "):-len(" -->")]
            marked[cur] = []
        elif line.startswith("<!-- end part: "):
            cur = None
        elif cur is None:
            legacy.append(line)
        else:
            marked[cur].append(line)
    return legacy, marked


def _headed(lines: list[str]) -> tuple[list[str], list[list[str]]]:
    """Lines before the first '## ' heading, and the '## ' sections."""
    head, secs = [], []
    for ln in lines:
        if ln.startswith("## "):
            secs.append([ln])
        elif secs:
            secs[-1].append(ln)
        else:
            head.append(ln)
    return head, secs


def page(old: str, head: list[str], new: dict, order) -> str:
    """A page from the parts run now (``new``: part -> lines) and, for the others, the old page's sections.
    Every part is written between markers; text of older pages without markers is kept section by section
    ('## ' headings), except the sections whose headings a part run now writes again."""
    legacy, marked = _sections(old)
    lhead, lsecs = _headed(legacy)
    rewritten = {ln for lines in new.values() for ln in lines if ln.startswith("## ")}
    out = list(head) if head or not "".join(lhead).strip() else lhead
    for sec in lsecs:
        if sec[0] not in rewritten:
            out += sec
    while out and not out[-1].strip():
        out.pop()
    out.append("")
    for p in order:
        lines = new.get(p, marked.get(p))
        if lines is None:
            continue
        while lines and not lines[-1].strip():
            lines = lines[:-1]
        out += [f"<!-- part: {p} -->", *lines, f"<!-- end part: {p} -->", ""]
    return "\n".join(out)
