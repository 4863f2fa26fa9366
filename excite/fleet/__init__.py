"""Many drives at once: the CI gate over a manifest of routes (:mod:`.batch`) and mining long
logs for the windows worth calibrating from (:mod:`.mine`), both on the engine of
:mod:`excite.core.engine` (local processes or a Dask cluster)."""
