"""What the project's long jobs share so that nothing is lost when they are stopped:
result files written whole (`files`) and SIGTERM taken as Ctrl-C, never dropped
(`signals`)."""
