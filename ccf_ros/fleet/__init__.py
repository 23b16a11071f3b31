"""``ccf fleet``: filter, score and health-check many bags on Dask (a local cluster by default, or an existing one).

Modules: :mod:`.discover` (inputs -> bags), :mod:`.keys` (resume keys), :mod:`.task` (one bag, on a worker),
:mod:`.health` (IMU health metrics and flags), :mod:`.run` (the driver), :mod:`.report` (Markdown + PNG).
Dask is imported only when a run starts (the ``fleet`` extra).
"""

__all__: list[str] = []
