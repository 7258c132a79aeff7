"""Subcommands of `davio`, discovered automatically; ORDER fixes their order in --help."""

ORDER = ["demo", "info", "run", "live", "calibrate", "map", "simulate", "eval", "bench", "export-da3",
         "export-xfeat"]
