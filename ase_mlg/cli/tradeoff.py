from ..tradeoff import add_tradeoff_parser as add_parser, run_tradeoff_command as run  # noqa: F401 (moved here next)
