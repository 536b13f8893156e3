"""motiontwin: Modelica models of precision motion systems as FMUs, co-simulation, identification, tuning
and mismatch diagnosis.

The library layers point down only: ``motiontwin.fmus`` (Modelica -> FMU) <- ``motiontwin.harness``
(co-simulation, recordings) <- ``motiontwin.ident`` (identification, tuning, diagnosis) <- the application
in this package (the ``motiontwin`` command, the demo, the paper comparison).
"""
__version__ = "0.1.0"
