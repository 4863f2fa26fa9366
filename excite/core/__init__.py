"""The ground floor: SO(3) helpers, the bounds of every input, units for people, the thread pool
and the engine that runs independent tasks on local processes or a Dask cluster (:mod:`.engine`).
Imports nothing else of excite but :mod:`excite.errors`."""
