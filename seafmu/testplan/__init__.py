"""``seafmu testplan``: the hydrodynamic test plan (AAUSHIP method one and two) as a command.

design (trials from the vessel file) -> scenarios with the ``axis_trial`` controller -> run against
the plant or a vessel (hardware link) -> measured trials (written for ``seafmu identify``) ->
damping fits (fit.py) -> vessel file with the identified damping -> report (report.py).

The package imports nothing itself, so building the ``seafmu`` parser (``cli.add_parser``) stays
cheap; ``runner.run_testplan`` is the entry point.
"""
