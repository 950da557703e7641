"""Helpers shared by the RDF tests (test_analysis, test_rdf_trajectories,
test_mda_rdf, test_mda_rdf_s)."""

import warnings

import MDAnalysis as mda


def universe(*files):
    """``mda.Universe(*files)`` without its warnings (guessed attributes,
    missing masses, ...)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return mda.Universe(*files)


def backend_params(cls):
    """The parameters of MDAnalysisTests' ``client_<cls>`` fixture
    (MDAnalysisTests/analysis/conftest.py): every parallel backend ``cls``
    supports and that is installed, with 2 workers, plus serial."""
    from MDAnalysis.lib.util import is_installed
    params = [{"backend": b, "n_workers": 2} for b in cls.get_supported_backends()
              if b != "serial" and is_installed(b)]
    return params + [{"backend": "serial"}]
