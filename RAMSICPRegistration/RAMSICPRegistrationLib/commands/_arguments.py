"""Argument types the commands share: each converts a string or says, in one line, what to give instead."""

import argparse
import math


def number(kind, test, requirement):
    """An argparse type: ``kind(text)`` that passes ``test``, else one line saying what to give."""

    def convert(text):
        try:
            value = kind(text)
        except ValueError:
            value = None
        if value is None or (kind is float and not math.isfinite(value)) or not test(value):
            raise argparse.ArgumentTypeError(f"{text!r}: {requirement}")
        return value

    return convert


POSITIVE_MM = number(float, lambda value: value > 0, "give a positive number of mm")
FINITE = number(float, lambda value: True, "give a finite number")
COUNT = number(int, lambda value: value >= 1, "give a whole number, 1 or more")
SEED = number(int, lambda value: value >= 0, "give a whole number, 0 or more")
SPEED = number(float, lambda value: value > 0, "give a speed above 0 mm/s")


def threshold(text):
    """``ramsicp ipc --threshold``: a number of HU that can separate bone from soft tissue, or 'auto' (Otsu)."""
    from ..image.hounsfield import check_bone_threshold

    if text == "auto":
        return text
    value = number(float, lambda value: True, "give a number of HU or 'auto'")(text)
    try:
        return check_bone_threshold(value)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None
