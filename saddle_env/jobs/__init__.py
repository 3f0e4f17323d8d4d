"""What the project's long jobs share: result files written whole (`files`), SIGTERM taken
as Ctrl-C, never dropped (`signals`), so that nothing is lost when they are stopped, and
BLAS pinned to one thread where numba or the job itself owns the cores (`blas`)."""
