"""The overlay drawn under every recorded frame: which worker acts, the manager's probabilities, the gaps."""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from functools import lru_cache

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from sb3_hddpg.media.trace import StepRecord

#: Height of the panel under the frame; 400 + 80 keeps both sides multiples of 16 (what H.264 wants).
PANEL_HEIGHT = 80

#: Colours of the two paper workers (the goal's green matches the drawn goal); others come from a palette.
WORKER_COLOURS: dict[str, tuple[int, int, int]] = {"goal": (30, 150, 60), "avoid": (230, 100, 20)}
_PALETTE = [(31, 119, 180), (148, 103, 189), (140, 86, 75), (227, 119, 194), (23, 190, 207), (188, 189, 34)]
_PANEL = (245, 245, 245)
_TEXT = (30, 30, 30)
_MUTED = (120, 120, 120)
_BAR_BACK = (222, 222, 222)


def worker_colour(name: str, names: Sequence[str] = ()) -> tuple[int, int, int]:
    """A stable colour for a worker: the paper workers' own, else a palette entry by position in ``names``."""
    if name in WORKER_COLOURS:
        return WORKER_COLOURS[name]
    others = [n for n in names if n not in WORKER_COLOURS]
    index = others.index(name) if name in others else zlib.crc32(name.encode())
    return _PALETTE[index % len(_PALETTE)]


@lru_cache(maxsize=4)
def _font(size: int) -> ImageFont.ImageFont | ImageFont.FreeTypeFont:
    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1 has only the fixed bitmap font
        return ImageFont.load_default()


def compose_frame(
    frame: np.ndarray, record: StepRecord, names: Sequence[str] = (), title: str = ""
) -> np.ndarray:
    """
    The env's frame with a panel underneath: the step, the acting worker (and a border of its colour around
    the frame), one probability bar per worker, the nearest obstacle's clearance and the goal distance
    (where the env reports them, as the snake arm does; else the step's raw reward terms).

    A frame whose sides are not multiples of 16 (another env's) is padded to them, which is what H.264
    wants; the snake arm's 400 x 400 is kept as it is.

    :param frame: the env's ``(H, W, 3)`` uint8 frame.
    :param record: what happened at this step.
    :param names: the workers the policy selects among (empty for a plain policy: no bars).
    :param title: a label for the policy, drawn at the panel's top left.
    :return: a ``(H + PANEL_HEIGHT, W, 3)`` uint8 frame (``H`` and ``W`` rounded up to multiples of 16).
    """
    height, width = (-(-side // 16) * 16 for side in frame.shape[:2])
    image = Image.new("RGB", (width, height + PANEL_HEIGHT), _PANEL)
    image.paste(Image.fromarray(frame), (0, 0))
    pen = ImageDraw.Draw(image)
    small, large = _font(12), _font(15)
    names = list(names) or sorted(record.probabilities)

    if record.selected is not None:
        colour = worker_colour(record.selected, names)
        pen.rectangle((0, 0, width - 1, height - 1), outline=colour, width=4)
        pen.text((10, 8), f"acting: {record.selected}", fill=colour, font=large)

    if title:
        # The policy's label, top right of the frame, clear of the acting worker's label.
        label_width = pen.textlength(title, font=small)
        pen.text((width - 10 - label_width, 10), title, fill=_MUTED, font=small)

    top = height + 6
    pen.text((8, top), f"episode {record.episode + 1}   step {record.step + 1}", fill=_TEXT, font=small)
    if np.isnan(record.min_clearance) and np.isnan(record.distance_to_goal):
        # An env without the snake's gaps: its raw reward terms, two to a line.
        terms = [f"{name[:10]} {value:.3g}" for name, value in record.reward_terms.items()]
        for line, start in enumerate(range(0, min(len(terms), 4), 2)):
            pen.text((8, top + 20 + 20 * line), "   ".join(terms[start : start + 2]), fill=_TEXT, font=small)
    else:
        collision = "  CONTACT" if record.collision else ""
        pen.text(
            (8, top + 20),
            f"obstacle gap {record.min_clearance:.3f}{collision}",
            fill=(200, 30, 30) if record.collision else _TEXT,
            font=small,
        )
        touched = "  TOUCH" if record.goal_touched else ""
        pen.text(
            (8, top + 40), f"goal distance {record.distance_to_goal:.3f}{touched}", fill=_TEXT, font=small
        )

    if names and record.probabilities:
        left = width // 2 + 5
        bar_left, bar_width = left + 52, width - (left + 52) - 42
        pen.text((left, top), "manager's probabilities", fill=_MUTED, font=small)
        for i, name in enumerate(names):
            y = top + 20 + i * 20
            if y + 14 > height + PANEL_HEIGHT:
                break
            p = record.probabilities.get(name, 0.0)
            colour = worker_colour(name, names)
            pen.text((left, y), name[:8], fill=colour, font=small)
            pen.rectangle((bar_left, y + 2, bar_left + bar_width, y + 12), fill=_BAR_BACK)
            pen.rectangle((bar_left, y + 2, bar_left + round(p * bar_width), y + 12), fill=colour)
            if name == record.selected:
                pen.rectangle((bar_left - 1, y + 1, bar_left + bar_width + 1, y + 13), outline=_TEXT, width=1)
            pen.text((bar_left + bar_width + 5, y), f"{p:.0%}", fill=_TEXT, font=small)
    return np.asarray(image, dtype=np.uint8)
