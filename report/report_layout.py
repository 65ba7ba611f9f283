"""A small page-layout engine on matplotlib's PDF backend.

The report is a list of blocks (:class:`Heading`, :class:`Paragraph`, :class:`Bullets`,
:class:`Figure`, :class:`Table`, :class:`Note`, :class:`PageBreak`). :func:`layout` flows
them onto A4 pages and returns the pages as lists of drawing operations, so the page
count and the page of every heading are known before anything is drawn (the contents
list and the tests use them); :func:`render` then draws the pages with ``PdfPages``.

Text is wrapped by measuring every candidate line with matplotlib's own font metrics, so
no line runs past the margin; table cells wrap inside their columns and tables split
between rows, repeating the header. Lengths are in inches, y measured down from the top.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cache, lru_cache
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.image as mpimg  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.backends.backend_agg import RendererAgg  # noqa: E402
from matplotlib.backends.backend_pdf import PdfPages  # noqa: E402
from matplotlib.font_manager import FontProperties  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402

PAGE_WIDTH, PAGE_HEIGHT = 8.27, 11.69  # A4 portrait
MARGIN_X, MARGIN_TOP, MARGIN_BOTTOM = 0.95, 0.85, 0.9
TEXT_WIDTH = PAGE_WIDTH - 2 * MARGIN_X
BODY_SIZE = 10.0
LINE_FACTOR = 1.38  # line height / font size
WIDTH_SAFETY = 1.02  # the PDF backend's glyph widths differ slightly from Agg's
HEADING_SIZES = {0: 20.0, 1: 15.0, 2: 12.0}
KEEP_WITH_NEXT = 1.2  # a heading needs this much room below it, else it starts a page
NOTE_COLOUR = "#9a3412"
PDF_METADATA = {
    "Title": "Reinforcement learning assignment report",
    "Creator": "report/build_report.py",
    "CreationDate": None,  # no timestamps: the same inputs give the same bytes
    "ModDate": None,
}


# --------------------------------------------------------------------------- blocks
@dataclass(frozen=True)
class Heading:
    """A section heading; level 1 starts a new page, level 2 flows with the text."""

    text: str
    level: int = 2
    in_contents: bool = True


@dataclass(frozen=True)
class Paragraph:
    text: str
    size: float = BODY_SIZE
    style: str = "normal"  # or "italic"
    weight: str = "normal"
    align: str = "left"  # or "center"
    space_after: float = 0.09


@dataclass(frozen=True)
class Bullets:
    items: tuple[str, ...]
    size: float = BODY_SIZE


@dataclass(frozen=True)
class Figure:
    """An embedded PNG, as wide as the text (or ``max_height`` tall), with a caption."""

    path: Path
    caption: str
    max_height: float = 4.6


@dataclass(frozen=True)
class Table:
    """A text table; ``widths`` are relative column widths (normalised to the text width)."""

    header: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]
    widths: tuple[float, ...] | None = None
    caption: str = ""
    size: float = 8.0


@dataclass(frozen=True)
class Note:
    """A highlighted remark, used for inputs that are not available."""

    text: str


@dataclass(frozen=True)
class PageBreak:
    pass


Block = Heading | Paragraph | Bullets | Figure | Table | Note | PageBreak


# --------------------------------------------------------------------------- text metrics
_RENDERER = RendererAgg(10, 10, 720)  # 720 dpi: widths to 0.1 pt


@cache
def _font(size: float, style: str = "normal", weight: str = "normal") -> FontProperties:
    return FontProperties(family="DejaVu Sans", size=size, style=style, weight=weight)


@lru_cache(maxsize=100_000)
def text_width(text: str, size: float, style: str = "normal", weight: str = "normal") -> float:
    """Width of ``text`` in inches when drawn at ``size`` points."""
    width, _, _ = _RENDERER.get_text_width_height_descent(
        text, _font(size, style, weight), ismath=False
    )
    return width / 720.0 * WIDTH_SAFETY


def line_height(size: float) -> float:
    return size * LINE_FACTOR / 72.0


def wrap(
    text: str, width: float, size: float, style: str = "normal", weight: str = "normal"
) -> list[str]:
    """Greedy word wrap of ``text`` into lines no wider than ``width`` inches; explicit
    newlines start new lines; a single word wider than the line is split by characters."""
    lines: list[str] = []
    for raw in text.split("\n"):
        current = ""
        for word in raw.split(" "):
            candidate = word if not current else f"{current} {word}"
            if text_width(candidate, size, style, weight) <= width:
                current = candidate
                continue
            if current:
                lines.append(current)
            while text_width(word, size, style, weight) > width and len(word) > 1:
                cut = len(word) - 1
                while cut > 1 and text_width(word[:cut], size, style, weight) > width:
                    cut -= 1
                lines.append(word[:cut])
                word = word[cut:]
            current = word
        lines.append(current)
    return lines


# --------------------------------------------------------------------------- operations
@dataclass(frozen=True)
class TextOp:
    x: float
    y: float  # top of the line
    text: str
    size: float
    style: str = "normal"
    weight: str = "normal"
    colour: str = "black"
    ha: str = "left"


@dataclass(frozen=True)
class ImageOp:
    x: float
    y: float
    width: float
    height: float
    path: Path


@dataclass(frozen=True)
class LineOp:
    x0: float
    x1: float
    y: float
    width: float = 0.6


@dataclass(frozen=True)
class BoxOp:
    x: float
    y: float
    width: float
    height: float
    colour: str


@dataclass
class Page:
    ops: list = field(default_factory=list)
    number: int | None = None  # printed page number (None: no footer)


@dataclass
class LaidOut:
    """The result of :func:`layout`: pages and the page of each contents heading."""

    pages: list[Page]
    headings: list[tuple[str, int, int]]  # (text, level, page number)


@lru_cache(maxsize=64)
def image_aspect(path: Path) -> float:
    """Height / width of a PNG."""
    image = mpimg.imread(path)
    return image.shape[0] / image.shape[1]


class _Flow:
    """The cursor of :func:`layout`."""

    def __init__(self, first_number: int) -> None:
        self.pages: list[Page] = []
        self.headings: list[tuple[str, int, int]] = []
        self.next_number = first_number
        self.new_page()

    @property
    def page(self) -> Page:
        return self.pages[-1]

    @property
    def bottom(self) -> float:
        return PAGE_HEIGHT - MARGIN_BOTTOM

    def new_page(self) -> None:
        self.pages.append(Page(number=self.next_number))
        self.next_number += 1
        self.y = MARGIN_TOP

    def at_top(self) -> bool:
        return self.y <= MARGIN_TOP + 1e-9

    def ensure(self, height: float) -> None:
        if self.y + height > self.bottom and not self.at_top():
            self.new_page()

    def text_lines(self, lines: list[str], size: float, x: float = MARGIN_X, **style) -> None:
        step = line_height(size)
        for line in lines:
            self.ensure(step)
            self.page.ops.append(TextOp(x, self.y, line, size, **style))
            self.y += step


def _heading(flow: _Flow, block: Heading) -> None:
    if block.level <= 1 and not flow.at_top():
        flow.new_page()
    size = HEADING_SIZES.get(block.level, BODY_SIZE)
    lines = wrap(block.text, TEXT_WIDTH, size, weight="bold")
    flow.ensure(len(lines) * line_height(size) + KEEP_WITH_NEXT)
    if not flow.at_top():
        flow.y += 0.12
    if block.in_contents:
        flow.headings.append((block.text, block.level, flow.page.number or 0))
    flow.text_lines(lines, size, weight="bold", colour="#1f3a5f")
    if block.level <= 1:
        flow.page.ops.append(LineOp(MARGIN_X, MARGIN_X + TEXT_WIDTH, flow.y + 0.02, 0.8))
        flow.y += 0.12
    else:
        flow.y += 0.04


def _paragraph(flow: _Flow, block: Paragraph) -> None:
    lines = wrap(block.text, TEXT_WIDTH, block.size, block.style, block.weight)
    if block.align == "center":
        x, ha = MARGIN_X + TEXT_WIDTH / 2, "center"
    else:
        x, ha = MARGIN_X, "left"
    flow.text_lines(lines, block.size, x, style=block.style, weight=block.weight, ha=ha)
    flow.y += block.space_after


def _bullets(flow: _Flow, block: Bullets) -> None:
    indent = 0.22
    for item in block.items:
        lines = wrap(item, TEXT_WIDTH - indent, block.size)
        flow.ensure(line_height(block.size))
        flow.page.ops.append(TextOp(MARGIN_X + 0.06, flow.y, "•", block.size))
        flow.text_lines(lines, block.size, MARGIN_X + indent)
        flow.y += 0.04
    flow.y += 0.06


def _note(flow: _Flow, block: Note) -> None:
    size = 9.0
    lines = wrap(block.text, TEXT_WIDTH - 0.3, size, "italic")
    height = len(lines) * line_height(size) + 0.12
    flow.ensure(height)
    flow.page.ops.append(BoxOp(MARGIN_X, flow.y, TEXT_WIDTH, height, NOTE_COLOUR))
    flow.y += 0.06
    flow.text_lines(lines, size, MARGIN_X + 0.15, style="italic", colour=NOTE_COLOUR)
    flow.y += 0.16


def _figure(flow: _Flow, block: Figure) -> None:
    aspect = image_aspect(Path(block.path))
    width = TEXT_WIDTH
    height = width * aspect
    if height > block.max_height:
        height = block.max_height
        width = height / aspect
    caption = wrap(block.caption, TEXT_WIDTH, 8.5, "italic")
    total = height + 0.1 + len(caption) * line_height(8.5)
    room = flow.bottom - flow.y
    if total > room >= 0.7 * total:  # shrink a little rather than leave a gap
        height -= total - room
        width = height / aspect
        total = room
    flow.ensure(total)
    if flow.y + total > flow.bottom:  # taller than a page even at the top: shrink
        height = flow.bottom - flow.y - 0.1 - len(caption) * line_height(8.5)
        width = height / aspect
    x = MARGIN_X + (TEXT_WIDTH - width) / 2
    flow.page.ops.append(ImageOp(x, flow.y, width, height, Path(block.path)))
    flow.y += height + 0.08
    flow.text_lines(caption, 8.5, style="italic", colour="#333333")
    flow.y += 0.14


def column_widths(block: Table, weights: tuple[float, ...], pad: float) -> list[float]:
    """Column widths in inches: proportional to ``weights``, but every column at least as
    wide as its longest word (header bold), taking the room from the other columns."""
    total = sum(weights)
    widths = [TEXT_WIDTH * w / total for w in weights]
    needed = []
    for j, head in enumerate(block.header):
        words = [(w, "bold") for w in head.split()]
        words += [(w, "normal") for row in block.rows for w in row[j].split()]
        needed.append(
            max((text_width(w, block.size, weight=b) for w, b in words), default=0) + 2 * pad
        )
    for _ in range(len(widths)):
        short = [j for j in range(len(widths)) if widths[j] < needed[j] - 1e-9]
        if not short:
            break
        extra = sum(needed[j] - widths[j] for j in short)
        donors = [j for j in range(len(widths)) if j not in short and widths[j] > needed[j]]
        room = sum(widths[j] - needed[j] for j in donors)
        if room <= 0:
            break
        take = min(1.0, extra / room)
        for j in donors:
            widths[j] -= (widths[j] - needed[j]) * take
        for j in short:
            widths[j] = min(needed[j], widths[j] + (needed[j] - widths[j]) * room / extra)
    return widths


def _table_rows(block: Table) -> tuple[list[float], list[list[list[str]]], list[list[str]]]:
    n = len(block.header)
    weights = block.widths or tuple(1.0 for _ in range(n))
    if len(weights) != n or any(len(row) != n for row in block.rows):
        raise ValueError(f"table with {n} columns got rows/widths of another length")
    pad = 0.05
    widths = column_widths(block, weights, pad)
    header = [
        wrap(h, w - 2 * pad, block.size, weight="bold")
        for h, w in zip(block.header, widths, strict=True)
    ]
    rows = [
        [wrap(c, w - 2 * pad, block.size) for c, w in zip(row, widths, strict=True)]
        for row in block.rows
    ]
    return widths, rows, header


def _table(flow: _Flow, block: Table) -> None:
    widths, rows, header = _table_rows(block)
    step, pad = line_height(block.size), 0.05
    lefts = [MARGIN_X + sum(widths[:i]) for i in range(len(widths))]
    right = MARGIN_X + TEXT_WIDTH

    def draw_row(cells: list[list[str]], weight: str) -> None:
        height = max(len(c) for c in cells) * step + 0.06
        for left, lines in zip(lefts, cells, strict=False):
            for k, line in enumerate(lines):
                op = TextOp(left + pad, flow.y + 0.03 + k * step, line, block.size, weight=weight)
                flow.page.ops.append(op)
        flow.y += height

    def draw_header() -> None:
        flow.page.ops.append(LineOp(MARGIN_X, right, flow.y, 0.9))
        draw_row(header, "bold")
        flow.page.ops.append(LineOp(MARGIN_X, right, flow.y, 0.6))

    header_height = max(len(c) for c in header) * step + 0.06
    heights = [max(len(c) for c in cells) * step + 0.06 for cells in rows]
    caption = len(wrap(block.caption, TEXT_WIDTH, 8.5, "italic")) if block.caption else 0
    whole = header_height + sum(heights) + 0.1 + caption * line_height(8.5)
    usable = PAGE_HEIGHT - MARGIN_TOP - MARGIN_BOTTOM
    flow.ensure(whole if whole < 0.5 * usable else header_height + (heights[:1] or [0])[0] + 0.1)
    draw_header()
    for cells in rows:
        height = max(len(c) for c in cells) * step + 0.06
        if flow.y + height > flow.bottom:
            flow.page.ops.append(LineOp(MARGIN_X, right, flow.y, 0.9))
            flow.new_page()
            draw_header()
        draw_row(cells, "normal")
    flow.page.ops.append(LineOp(MARGIN_X, right, flow.y, 0.9))
    flow.y += 0.06
    if block.caption:
        caption = wrap(block.caption, TEXT_WIDTH, 8.5, "italic")
        flow.text_lines(caption, 8.5, style="italic", colour="#333333")
    flow.y += 0.14


def layout(blocks: list[Block], first_number: int = 1) -> LaidOut:
    """Flow ``blocks`` onto pages numbered from ``first_number``."""
    flow = _Flow(first_number)
    handlers = {Heading: _heading, Paragraph: _paragraph, Bullets: _bullets, Note: _note,
                Figure: _figure, Table: _table}  # fmt: skip
    for block in blocks:
        if isinstance(block, PageBreak):
            if not flow.at_top():
                flow.new_page()
            continue
        handlers[type(block)](flow, block)
    if len(flow.pages) > 1 and not flow.pages[-1].ops:
        flow.pages.pop()
    return LaidOut(flow.pages, flow.headings)


# --------------------------------------------------------------------------- drawing
def _draw(fig: plt.Figure, page: Page) -> None:
    def fx(x: float) -> float:
        return x / PAGE_WIDTH

    def fy(y: float) -> float:
        return 1.0 - y / PAGE_HEIGHT

    for op in page.ops:
        if isinstance(op, TextOp):
            fig.text(fx(op.x), fy(op.y), op.text, fontsize=op.size, fontstyle=op.style,
                     fontweight=op.weight, color=op.colour, ha=op.ha, va="top",
                     family="DejaVu Sans", parse_math=False)  # fmt: skip
        elif isinstance(op, ImageOp):
            ax = fig.add_axes(
                (fx(op.x), fy(op.y + op.height), fx(op.width), op.height / PAGE_HEIGHT)
            )
            ax.imshow(mpimg.imread(op.path), interpolation="antialiased")
            ax.set_axis_off()
        elif isinstance(op, LineOp):
            fig.add_artist(Line2D([fx(op.x0), fx(op.x1)], [fy(op.y), fy(op.y)],
                                  linewidth=op.width, color="#444444"))  # fmt: skip
        elif isinstance(op, BoxOp):
            fig.add_artist(Rectangle((fx(op.x), fy(op.y + op.height)), fx(op.width),
                                     op.height / PAGE_HEIGHT, facecolor="#fff7ed",
                                     edgecolor=op.colour, linewidth=0.8))  # fmt: skip
    if page.number is not None:
        fig.text(0.5, fy(PAGE_HEIGHT - 0.45), str(page.number), ha="center", va="top",
                 fontsize=9, color="#555555", parse_math=False)  # fmt: skip


def render(pages: list[Page], output: Path) -> Path:
    """Draw ``pages`` into the PDF ``output`` (no creation date: same input, same bytes)."""
    output = Path(output)
    output.parent.mkdir(parents=True, exist_ok=True)
    temporary = output.with_name(output.name + ".tmp")
    with PdfPages(temporary, metadata=PDF_METADATA) as pdf:
        for page in pages:
            fig = plt.figure(figsize=(PAGE_WIDTH, PAGE_HEIGHT))
            _draw(fig, page)
            pdf.savefig(fig)
            plt.close(fig)
    temporary.replace(output)
    return output
