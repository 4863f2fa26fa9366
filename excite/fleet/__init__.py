"""Many drives at once: the engine that runs independent tasks on local processes or a Dask
cluster (:mod:`.engine`), the CI gate over a manifest of routes (:mod:`.batch`) and mining long
logs for the windows worth calibrating from (:mod:`.mine`)."""
