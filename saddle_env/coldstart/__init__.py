"""The tools for a process's first call, above the simulator and the environments they run:
building the install's ahead-of-time compiled kernels (`aot_build`, which
`saddle_env.compilation.aot` loads), compiling ahead into numba's on-disk cache or running
that build again (`precompile`), and measuring where a first call's compile time goes
(`profile`). docs/coldstart.md explains the first call's cost."""
