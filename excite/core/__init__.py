"""The ground floor: SO(3) helpers, the bounds of every input, units for people, the thread pool
and the compiled small linear algebra. Imports nothing else of excite but :mod:`excite.errors`."""
