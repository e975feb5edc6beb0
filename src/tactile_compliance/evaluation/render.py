"""A tiny document model (headings, paragraphs, tables, figures) and its three renderers.

Tables carry numbers, not strings, so each renderer typesets them its own way.
Plain f-strings, no template engine: the package must not grow a dependency for this.
"""

from __future__ import annotations

import base64
import html
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

__all__ = [
    "Block",
    "Cell",
    "Figure",
    "Heading",
    "Note",
    "Paragraph",
    "Table",
    "format_mean_std",
    "render_html",
    "render_latex",
    "render_markdown",
]


# ============================================================================ blocks
@dataclass
class Cell:
    """One table cell: a number (optionally ``mean ± std``) or plain text."""

    value: float | None = None
    std: float | None = None
    text: str | None = None
    bold: bool = False
    digits: int = 4

    @property
    def empty(self) -> bool:
        return self.text is None and (self.value is None or _nan(self.value))

    def plain(self) -> str:
        """The cell as plain text (no emphasis): what Markdown/HTML show inside the bold."""
        if self.text is not None:
            return self.text
        return format_mean_std(self.value, self.std, self.digits)


def _nan(value: float | None) -> bool:
    return value is None or (isinstance(value, float) and math.isnan(value))


def format_mean_std(mean: float | None, std: float | None = None, digits: int = 4) -> str:
    """``0.8990 ± 0.0094``; a missing std (a single run) prints the mean alone; no mean: ``–``."""
    if _nan(mean):
        return "–"
    text = f"{mean:.{digits}f}"
    if not _nan(std):
        text += f" ± {std:.{digits}f}"
    return text


@dataclass
class Table:
    """A table. ``groups``: an upper header row of ``(label, span)`` pairs; ``rules_after``:
    body rows followed by a rule; ``caption`` goes above, ``provenance`` below; ``label``
    is file-name safe; ``latex_columns``: ``columns`` with LaTeX markup."""

    title: str
    columns: list[str]
    rows: list[list[Cell]]
    groups: list[tuple[str, int]] | None = None
    rules_after: set[int] = field(default_factory=set)
    caption: str = ""
    provenance: str = ""
    label: str = "table"
    latex_columns: list[str] | None = None


@dataclass
class Heading:
    text: str
    level: int = 2


@dataclass
class Paragraph:
    """Running text with backtick ``code`` spans; text whose every line starts with ``- `` is
    a bulleted list (Markdown reads it as one, the other formats use :attr:`items`)."""

    text: str

    @property
    def items(self) -> list[str] | None:
        """The entries when the paragraph is a bulleted list, else None."""
        lines = [line for line in self.text.split("\n") if line]
        if not all(line.startswith("- ") for line in lines):
            return None
        return [line[2:] for line in lines]


@dataclass
class Note:
    """Something the reader must know (a skipped table, a warning): rendered highlighted."""

    text: str


@dataclass
class Figure:
    path: Path
    caption: str
    provenance: str = ""
    label: str = "figure"


Block = Heading | Paragraph | Note | Table | Figure


# ============================================================================ Markdown
def _md_cell(cell: Cell) -> str:
    text = cell.plain().replace("|", "\\|")
    return f"**{text}**" if cell.bold and not cell.empty else text


def _md_table(table: Table) -> str:
    columns = list(table.columns)
    if table.groups:
        # Markdown has one header row: fold the group label into each column label.
        expanded: list[str] = []
        for label, span in table.groups:
            expanded.extend([label] * span)
        columns = [f"{g} {c}".strip() if g else c for g, c in zip(expanded, columns, strict=True)]
    lines = [
        "| " + " | ".join(c.replace("|", "\\|") for c in columns) + " |",
        "|" + "|".join("---" for _ in columns) + "|",
    ]
    lines += ["| " + " | ".join(_md_cell(c) for c in row) + " |" for row in table.rows]
    return "\n".join(lines)


def render_markdown(blocks: Sequence[Block], figure_root: Path) -> str:
    """Markdown document; figures are linked relative to ``figure_root`` (the report dir)."""
    out: list[str] = []
    for block in blocks:
        if isinstance(block, Heading):
            out.append(f"{'#' * block.level} {block.text}")
        elif isinstance(block, Paragraph):
            out.append(block.text)
        elif isinstance(block, Note):
            out.append(f"> **Note:** {block.text}")
        elif isinstance(block, Table | Figure):
            if isinstance(block, Table):
                parts = [f"**{block.title}.** {block.caption}".strip(), _md_table(block)]
            else:
                alt = block.caption.split(" — ")[0]  # "Fig. 5": the caption follows in full
                rel = _relative(block.path, figure_root)
                parts = [f"![{alt}]({rel})", f"*{block.caption}*"]
            if block.provenance:
                parts.append(f"*How produced:* {block.provenance}")
            out.append("\n\n".join(parts))
    return "\n\n".join(out) + "\n"


def _relative(path: Path, root: Path) -> str:
    try:
        return Path(path).resolve().relative_to(Path(root).resolve()).as_posix()
    except ValueError:
        return Path(path).as_posix()


# ============================================================================ HTML
_CODE = re.compile(r"`([^`]+)`")
_BOLD = re.compile(r"\*\*([^*]+)\*\*")

_CSS = """
body { font-family: -apple-system, 'Segoe UI', Helvetica, Arial, sans-serif; max-width: 1200px;
       margin: 2em auto; padding: 0 1em; color: #222; line-height: 1.45; }
table { border-collapse: collapse; margin: 0.6em 0; font-size: 0.92em; }
th, td { padding: 0.25em 0.7em; text-align: center; white-space: nowrap; }
thead tr:first-child th { border-top: 2px solid #222; }
thead tr:last-child th { border-bottom: 1px solid #222; }
tbody tr:last-child td { border-bottom: 2px solid #222; }
tr.rule td { border-bottom: 1px solid #999; }
td:first-child, th:first-child { text-align: left; }
.caption { font-weight: 600; margin-top: 1.4em; }
.prov { color: #555; font-size: 0.85em; margin: 0.2em 0 1.2em 0; }
.note { background: #fff6d6; border-left: 4px solid #e0b100; padding: 0.4em 0.8em; }
figure { margin: 1.2em 0; } figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: 0.9em; } code { background: #f3f3f3; padding: 0 0.2em; }
"""


def _html_inline(text: str) -> str:
    escaped = html.escape(text, quote=False)
    escaped = _CODE.sub(r"<code>\1</code>", escaped)
    return _BOLD.sub(r"<b>\1</b>", escaped)


def _html_provenance(text: str) -> str:
    return f'<div class="prov">How produced: {_html_inline(text)}</div>' if text else ""


def _html_table(table: Table) -> str:
    head: list[str] = []
    if table.groups:
        cells = "".join(
            f'<th colspan="{span}">{html.escape(label)}</th>' for label, span in table.groups
        )
        head.append(f"<tr>{cells}</tr>")
    head.append("<tr>" + "".join(f"<th>{html.escape(c)}</th>" for c in table.columns) + "</tr>")
    body: list[str] = []
    for index, row in enumerate(table.rows):
        cls = ' class="rule"' if index in table.rules_after else ""
        cells = [
            f"<td><b>{html.escape(c.plain())}</b></td>"
            if c.bold and not c.empty
            else f"<td>{html.escape(c.plain())}</td>"
            for c in row
        ]
        body.append(f"<tr{cls}>{''.join(cells)}</tr>")
    return (
        f'<div class="caption">{html.escape(table.title)}. {_html_inline(table.caption)}</div>\n'
        f"<table><thead>{''.join(head)}</thead><tbody>{''.join(body)}</tbody></table>\n"
        + _html_provenance(table.provenance)
    )


def render_html(blocks: Sequence[Block], title: str) -> str:
    """One self-contained HTML file (figures as base64 PNG data URIs), with a contents
    list of the level-2 sections after the title."""
    out: list[str] = []
    sections = [b for b in blocks if isinstance(b, Heading) and b.level == 2]
    anchors = {id(b): f"s{i}" for i, b in enumerate(sections)}
    for block in blocks:
        if isinstance(block, Heading):
            level = min(6, max(1, block.level))
            anchor = f' id="{anchors[id(block)]}"' if id(block) in anchors else ""
            out.append(f"<h{level}{anchor}>{_html_inline(block.text)}</h{level}>")
            if level == 1 and sections:
                items = "".join(
                    f'<li><a href="#{anchors[id(b)]}">{_html_inline(b.text)}</a></li>'
                    for b in sections
                )
                out.append(f"<nav><ul>{items}</ul></nav>")
        elif isinstance(block, Paragraph) and block.items is not None:
            items = "".join(f"<li>{_html_inline(item)}</li>" for item in block.items)
            out.append(f"<ul>{items}</ul>")
        elif isinstance(block, Paragraph):
            out.append(f"<p>{_html_inline(block.text)}</p>")
        elif isinstance(block, Note):
            out.append(f'<p class="note"><b>Note:</b> {_html_inline(block.text)}</p>')
        elif isinstance(block, Table):
            out.append(_html_table(block))
        elif isinstance(block, Figure):
            data = base64.b64encode(Path(block.path).read_bytes()).decode("ascii")
            out.append(
                f'<figure><img alt="{html.escape(block.caption)}" '
                f'src="data:image/png;base64,{data}"/>'
                f"<figcaption>{_html_inline(block.caption)}</figcaption>"
                f"{_html_provenance(block.provenance)}</figure>"
            )
    body = "\n".join(out)
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"/>'
        f"<title>{html.escape(title)}</title><style>{_CSS}</style></head>\n"
        f"<body>\n{body}\n</body></html>\n"
    )


# ============================================================================ LaTeX
_TEX_SPECIAL = {
    "\\": r"\textbackslash{}",
    "&": r"\&",
    "%": r"\%",
    "$": r"\$",
    "#": r"\#",
    "_": r"\_",
    "{": r"\{",
    "}": r"\}",
    "~": r"\textasciitilde{}",
    "^": r"\textasciicircum{}",
    "±": r"$\pm$",
    "–": "--",
    "—": "---",
    "≤": r"$\leq$",
    "≥": r"$\geq$",
    "²": r"$^2$",
    "₁₀": r"$_{10}$",
    "×": r"$\times$",
    "√": r"$\surd$",
    "·": r"$\cdot$",
    "…": r"\ldots{}",
    "½": r"$\frac{1}{2}$",
    "−": "-",
}
_TEX_PATTERN = re.compile(
    "|".join(re.escape(k) for k in sorted(_TEX_SPECIAL, key=len, reverse=True))
)


def tex_escape(text: str) -> str:
    """Escape LaTeX specials and map the few Unicode symbols the report uses; anything else
    beyond Latin script (an emoji in an error message) becomes ``?``, or pdflatex stops."""
    escaped = _TEX_PATTERN.sub(lambda m: _TEX_SPECIAL[m.group(0)], text)
    return "".join(ch if ord(ch) < 0x250 else "?" for ch in escaped)


def _tex_inline(text: str) -> str:
    # `code` -> \texttt{}, **bold** -> \textbf{}; escape everything else.
    out: list[str] = []
    pos = 0
    for match in re.finditer(r"`([^`]+)`|\*\*([^*]+)\*\*", text):
        out.append(tex_escape(text[pos : match.start()]))
        if match.group(1) is not None:
            out.append(r"\texttt{" + tex_escape(match.group(1)) + "}")
        else:
            out.append(r"\textbf{" + tex_escape(match.group(2)) + "}")
        pos = match.end()
    out.append(tex_escape(text[pos:]))
    return "".join(out)


def _tex_cell(cell: Cell) -> str:
    if cell.text is not None or cell.empty:
        text = tex_escape(cell.plain())
        return rf"\textbf{{{text}}}" if cell.bold and not cell.empty else text
    mean = f"{cell.value:.{cell.digits}f}"
    std = None if _nan(cell.std) else f"{cell.std:.{cell.digits}f}"
    if cell.bold:
        mean = rf"\mathbf{{{mean}}}"
        std = rf"\mathbf{{{std}}}" if std is not None else None
    return f"${mean} \\pm {std}$" if std is not None else f"${mean}$"


def latex_table(table: Table) -> str:
    """A booktabs ``table`` environment (needs ``\\usepackage{booktabs}``)."""
    n = len(table.columns)
    spec = "l" + "c" * (n - 1)
    columns = table.latex_columns or [tex_escape(c) for c in table.columns]
    lines = [
        r"\begin{table}[ht]",
        r"\centering",
        rf"\caption{{{_tex_inline(table.title)}. {_tex_inline(table.caption)}}}",
        rf"\label{{tab:{table.label}}}",
        r"\small",
        rf"\begin{{tabular}}{{@{{}}{spec}@{{}}}}",
        r"\toprule",
    ]
    if table.groups:
        cells, rules, start = [], [], 1
        for label, span in table.groups:
            if label:
                cells.append(rf"\multicolumn{{{span}}}{{c}}{{{tex_escape(label)}}}")
                rules.append(rf"\cmidrule(lr){{{start}-{start + span - 1}}}")
            else:
                cells.extend([""] * span)
            start += span
        lines.append(" & ".join(cells) + r" \\")
        lines.append(" ".join(rules))
    lines.append(" & ".join(columns) + r" \\")
    lines.append(r"\midrule")
    for index, row in enumerate(table.rows):
        lines.append(" & ".join(_tex_cell(c) for c in row) + r" \\")
        if index in table.rules_after and index != len(table.rows) - 1:
            lines.append(r"\midrule")
    lines += [r"\bottomrule", r"\end{tabular}"]
    if table.provenance:
        lines.append(
            rf"\par\smallskip\parbox{{0.95\linewidth}}{{\footnotesize "
            rf"How produced: {_tex_inline(table.provenance)}}}"
        )
    lines.append(r"\end{table}")
    return "\n".join(lines)


def render_latex(blocks: Sequence[Block], figure_root: Path, title: str) -> str:
    """A compilable LaTeX document (article, booktabs, graphicx); figures by relative path."""
    out = [
        r"\documentclass[10pt]{article}",
        r"\usepackage[margin=2cm,landscape]{geometry}",
        r"\usepackage[T1]{fontenc}",
        r"\usepackage{booktabs,graphicx,amssymb,float}",
        rf"\title{{{tex_escape(title)}}}",
        r"\date{}",
        r"\begin{document}",
        r"\maketitle",
    ]
    for block in blocks:
        if isinstance(block, Heading):
            if block.level <= 1:
                continue  # the document title already says it
            command = {2: "section", 3: "subsection"}.get(block.level, "subsubsection")
            out.append(rf"\{command}*{{{_tex_inline(block.text)}}}")
        elif isinstance(block, Paragraph) and block.items is not None:
            items = "\n".join(rf"\item {_tex_inline(item)}" for item in block.items)
            out.append(f"\\begin{{itemize}}\n{items}\n\\end{{itemize}}")
        elif isinstance(block, Paragraph):
            out.append(_tex_inline(block.text))
        elif isinstance(block, Note):
            out.append(
                rf"\noindent\fbox{{\parbox{{0.95\linewidth}}{{\textbf{{Note:}} "
                rf"{_tex_inline(block.text)}}}}}"
            )
        elif isinstance(block, Table):
            out.append(latex_table(block))
        elif isinstance(block, Figure):
            rel = _relative(block.path, figure_root)
            prov = (
                rf" \emph{{How produced:}} {_tex_inline(block.provenance)}"
                if block.provenance
                else ""
            )
            out.append(
                "\n".join(
                    [
                        r"\begin{figure}[H]",
                        r"\centering",
                        rf"\includegraphics[width=0.9\linewidth,height=0.75\textheight,"
                        rf"keepaspectratio]{{{rel}}}",
                        rf"\caption{{{_tex_inline(block.caption)}{prov}}}",
                        rf"\label{{fig:{block.label}}}",
                        r"\end{figure}",
                    ]
                )
            )
    out.append(r"\end{document}")
    return "\n\n".join(out) + "\n"
