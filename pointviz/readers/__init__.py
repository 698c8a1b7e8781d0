"""One reader per file format behind a registry (:mod:`.registry`); :func:`pointviz.io.load` is
the public entry point. Each format's header checks live with its reader; the numeric rows of
PLY, PCD and XYZ files are read by the core (:mod:`.table`)."""
