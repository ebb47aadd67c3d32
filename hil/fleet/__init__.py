"""A fleet's nightly diagnosis (``hil fleet``): many records of many axes, each diagnosed
(hil.ident.chain) and its tracked effects fitted, stored per record, and every axis judged
against its own history (statistical process control).

Modules: :mod:`~hil.fleet.manifest` (which records: a CSV or TOML manifest, or a folder),
:mod:`~hil.fleet.run` (one record's figures; local processes or a Dask cluster),
:mod:`~hil.fleet.batch` (the resumable run over a fleet), :mod:`~hil.fleet.spc` (control limits,
CUSUM, thresholds: pure functions), :mod:`~hil.fleet.summary` (the fleet judged),
:mod:`~hil.fleet.report` (the HTML page, CSV and JSON), :mod:`~hil.fleet.synth` (a fleet with a
known answer, for tests and the tutorial).
"""
