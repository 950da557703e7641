from ..analysis import add_rdf_parser as add_parser, run_rdf_command as run  # noqa: F401 (moved here next)
