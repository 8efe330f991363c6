"""One module per ``fusion-pf`` subcommand (see :mod:`fusion_pf.cli`)."""
