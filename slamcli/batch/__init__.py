"""Batch runs: a TOML manifest of ``slamcli run`` jobs, their pass/fail gates and the reports.

The modules here are pure: :mod:`.manifest` reads and validates a manifest, :mod:`.gates` parses
and evaluates ``fail_if`` gates against a run's ``run.json``, :mod:`.junit` and :mod:`.html`
write the JUnit XML and the self-contained HTML report. Running the jobs lives elsewhere.
"""
