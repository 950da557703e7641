"""The pair source of both RDF front ends: one MLG kept across frames
(docs/design.md §10), and how the count kernels split its pairs."""

import numpy as np
from ..jit import njit

from ..parallel import reduction_chunks
from ..verletlist import VerletList

__all__ = ["PairSource", "n_chunks", "chunk_bounds", "chunk_totals"]


class PairSource:
    """Unordered pairs within a cutoff, one list a frame on one MLG kept
    across frames (a :class:`~ase_mlg.verletlist.VerletList` without skin;
    a new box builds a new grid).

    ``template=None``: every pair with ``d < cutoff``, all images (exact
    query); an odd ``template`` W: the pairs Boris's W^3 half template
    sees (minimum image, approximate).
    """

    def __init__(self, template=None):
        self.template = template
        self.verlet_list = VerletList(0.0, template=template, block=2, follow_cell=False)

    def __call__(self, positions, cell, pbc, cutoff, want_S=False):
        """Return ``i, j, S`` (S is None unless ``want_S``): each unordered
        pair once, ``i != j`` or an atom with its own periodic image.
        ``positions`` (Å), ``cell`` (3x3, Å), ``cutoff`` (Å)."""
        vl = self.verlet_list
        vl.cutoff = cutoff
        vl.build(positions, cell, pbc)
        res = vl.arrays(half=True, quantities="ijS" if want_S else "ij")
        return res["i"], res["j"], res.get("S")

    def reset(self):
        """Forget the grid (other atoms): the next frame builds one."""
        self.verlet_list.reset()

    def stats(self):
        st = self.verlet_list.stats
        return {"builds": st["grid_builds"], "updates": st["grid_updates"]}


def n_chunks(npair):
    """Chunks for the threaded histogram kernels (the package's threading
    policy, :func:`ase_mlg.parallel.reduction_chunks`)."""
    return reduction_chunks(npair, 8192)


@njit(cache=True)
def chunk_bounds(npair, c, nchunk):
    """Pairs ``lo:hi`` of chunk ``c`` of ``nchunk``: contiguous chunks whose
    sizes differ by at most one, each histogrammed by one thread."""
    return npair * c // nchunk, npair * (c + 1) // nchunk


@njit(cache=True)
def chunk_totals(hist):
    """The chunks' integer counts (one row each) added bin by bin: a loop,
    not ``hist.sum(axis=0)``, whose numba implementation and its
    axis-bounds message compiled for 2.9 s of a first RDF (exact either
    way: integers)."""
    out = np.zeros(hist.shape[1], np.int64)
    for c in range(hist.shape[0]):
        for k in range(hist.shape[1]):
            out[k] += hist[c, k]
    return out
