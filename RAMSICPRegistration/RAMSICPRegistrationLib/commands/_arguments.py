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
    """``ramsicp ipc --threshold``: a number of HU, or 'auto' (Otsu)."""
    return text if text == "auto" else number(float, lambda value: True, "give a number of HU or 'auto'")(text)
