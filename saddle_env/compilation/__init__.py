"""numba's side of the package, apart from the physics, and the bottom layer under it:
compiling what a scene uses (`jit`, `specialise`), keeping the on-disk cache honest
(`cache`), saying when a compile takes a while (`notice`), loading the install's
ahead-of-time build (`aot`, `aot_threads`), and the threads compiled code runs on
(`threads`). It imports nothing of the package above `saddle_env.scene`; the tools that run
the simulator to compile or measure it ahead are in `saddle_env.coldstart`."""
