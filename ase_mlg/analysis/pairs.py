"""The pair source of both RDF front ends: one MLG kept across frames
(docs/design.md §10), and how the count kernels split its pairs."""

from numba import njit

from ..parallel import reduction_chunks
from ..query import exact_pairs
from ..template import template_pairs
from ..tracker import GridTracker

__all__ = ["PairSource", "n_chunks", "chunk_bounds"]


class PairSource:
    """Unordered pairs within a cutoff, from one MLG kept across frames
    (:class:`~ase_mlg.tracker.GridTracker`; a new box builds a new grid).

    ``template=None``: every pair with ``d < cutoff``, all images (exact
    query); an odd ``template`` W: the pairs Boris's W^3 half template
    sees (minimum image, approximate).
    """

    def __init__(self, template=None):
        self.template = template
        self.tracker = GridTracker(follow_cell=False)

    def __call__(self, positions, cell, pbc, cutoff, want_S=False):
        """Return ``i, j, S`` (S is None unless ``want_S``): each unordered
        pair once, ``i != j`` or an atom with its own periodic image.
        ``positions`` (Å), ``cell`` (3x3, Å), ``cutoff`` (Å)."""
        g = self.tracker.follow(positions, cell, pbc)
        if self.template is not None:
            i, j, S, _ = template_pairs(g, self.template, cutoff)
            return i, j, (S if want_S else None)
        return exact_pairs(g, cutoff, shifts=want_S)

    def stats(self):
        st = self.tracker.stats
        return {"builds": st["builds"], "updates": st["updates"]}


def n_chunks(npair):
    """Chunks for the threaded histogram kernels (the package's threading
    policy, :func:`ase_mlg.parallel.reduction_chunks`)."""
    return reduction_chunks(npair, 8192)


@njit(cache=True, inline="always")
def chunk_bounds(npair, c, nchunk):
    """Pairs ``lo:hi`` of chunk ``c`` of ``nchunk``: contiguous chunks whose
    sizes differ by at most one, each histogrammed by one thread."""
    return npair * c // nchunk, npair * (c + 1) // nchunk
