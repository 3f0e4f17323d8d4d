"""numba's side of the package, apart from the physics: compiling what a scene uses
(`jit`, `specialise`), keeping the on-disk cache honest (`cache`), saying when a compile
takes a while (`notice`), measuring compile time (`profile`), compiling ahead
(`precompile`; at install `aot_build`, loaded by `aot`), and the threads compiled code
runs on (`threads`)."""
