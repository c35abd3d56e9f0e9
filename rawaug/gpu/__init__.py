"""The Triton kernel of the fused noise chain (CUDA; CPU tensors under ``TRITON_INTERPRET=1``)."""
