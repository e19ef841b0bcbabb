"""Render a `tmux capture-pane -p -e` capture (text with SGR colour escapes) to a PNG.

Usage: render.py CAPTURE.ansi OUT.png

Handles what the console uses: reset, bold, dim, reverse, underline, the 16 basic
colours, 256-colour and RGB foreground/background. Font: DejaVu Sans Mono (Debian's
fonts-dejavu-core), or the path in $SCREENSHOT_FONT.
"""
import os
import re
import sys

from PIL import Image, ImageDraw, ImageFont

FONT = os.environ.get("SCREENSHOT_FONT", "/usr/share/fonts/truetype/dejavu/DejaVuSansMono.ttf")
BOLD = FONT.replace(".ttf", "-Bold.ttf")
SIZE = 16
BG = (24, 24, 28)
FG = (215, 215, 215)
BASIC = [
    (0, 0, 0), (205, 49, 49), (13, 188, 121), (229, 229, 16),
    (36, 114, 200), (188, 63, 188), (17, 168, 205), (229, 229, 229),
    (102, 102, 102), (241, 76, 76), (35, 209, 139), (245, 245, 67),
    (59, 142, 234), (214, 112, 214), (41, 184, 219), (255, 255, 255),
]


def color256(n):
    if n < 16:
        return BASIC[n]
    if n < 232:
        n -= 16
        steps = [0, 95, 135, 175, 215, 255]
        return (steps[n // 36], steps[(n // 6) % 6], steps[n % 6])
    v = 8 + (n - 232) * 10
    return (v, v, v)


def parse(text):
    """Yield rows of (char, fg, bg, bold, dim, reverse, underline)."""
    state = dict(fg=None, bg=None, bold=False, dim=False, rev=False, ul=False)
    rows = []
    for line in text.split("\n"):
        row = []
        for tok in re.split(r"(\x1b\[[0-9;]*m)", line):
            if tok.startswith("\x1b["):
                codes = [int(c) if c else 0 for c in tok[2:-1].split(";")]
                i = 0
                while i < len(codes):
                    c = codes[i]
                    if c == 0:
                        state.update(fg=None, bg=None, bold=False, dim=False, rev=False, ul=False)
                    elif c == 1:
                        state["bold"] = True
                    elif c == 2:
                        state["dim"] = True
                    elif c == 22:
                        state["bold"] = state["dim"] = False
                    elif c == 4:
                        state["ul"] = True
                    elif c == 24:
                        state["ul"] = False
                    elif c == 7:
                        state["rev"] = True
                    elif c == 27:
                        state["rev"] = False
                    elif 30 <= c <= 37:
                        state["fg"] = BASIC[c - 30]
                    elif 90 <= c <= 97:
                        state["fg"] = BASIC[c - 90 + 8]
                    elif c == 39:
                        state["fg"] = None
                    elif 40 <= c <= 47:
                        state["bg"] = BASIC[c - 40]
                    elif 100 <= c <= 107:
                        state["bg"] = BASIC[c - 100 + 8]
                    elif c == 49:
                        state["bg"] = None
                    elif c in (38, 48) and i + 2 < len(codes) and codes[i + 1] == 5:
                        state["fg" if c == 38 else "bg"] = color256(codes[i + 2])
                        i += 2
                    elif c in (38, 48) and i + 4 < len(codes) and codes[i + 1] == 2:
                        state["fg" if c == 38 else "bg"] = tuple(codes[i + 2:i + 5])
                        i += 4
                    i += 1
            else:
                for ch in tok:
                    row.append((ch, dict(state)))
        rows.append(row)
    while rows and not rows[-1]:
        rows.pop()
    return rows


def main(src, out):
    text = open(src, encoding="utf-8").read()
    rows = parse(text)
    font = ImageFont.truetype(FONT, SIZE)
    bold = ImageFont.truetype(BOLD, SIZE) if os.path.exists(BOLD) else font
    cw = round(font.getlength("M"))
    ch = SIZE + 4
    cols = max(80, max((len(r) for r in rows), default=0))
    img = Image.new("RGB", (cols * cw + 16, len(rows) * ch + 16), BG)
    d = ImageDraw.Draw(img)
    for y, row in enumerate(rows):
        for x, (c, s) in enumerate(row):
            fg, bg = s["fg"] or FG, s["bg"] or BG
            if s["dim"]:
                fg = tuple(v // 2 + BG[i] // 2 for i, v in enumerate(fg))
            if s["rev"]:
                fg, bg = bg, fg
            px, py = 8 + x * cw, 8 + y * ch
            if bg != BG:
                d.rectangle([px, py, px + cw - 1, py + ch - 1], fill=bg)
            if c != " ":
                d.text((px, py + 1), c, font=bold if s["bold"] else font, fill=fg)
            if s["ul"]:
                d.line([px, py + ch - 2, px + cw - 1, py + ch - 2], fill=fg)
    img.save(out)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
