"""The fused synthesis engine: per-sample parameters in one (B, P) tensor, every stage of
the noise chain applied in one pass per backend (numba on the CPU, Triton on CUDA)."""
