"""Option types and messages shared by the ``ase-mlg`` commands."""

import argparse

__all__ = ["is_tty", "int_at_least", "positive_int"]


def is_tty(stream):
    """True when ``stream`` is a terminal (progress bars only there)."""
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


def int_at_least(minimum):
    def parse(s):
        try:
            v = int(s)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {s!r}") from None
        if v < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum}, got {v}")
        return v
    return parse


positive_int = int_at_least(1)
