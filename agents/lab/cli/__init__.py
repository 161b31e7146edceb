"""The ``quadslam`` command (:mod:`agents.lab.cli.main`), its ``study`` subcommands and the
reference tables the documentation generates from the parsers and config specs."""
