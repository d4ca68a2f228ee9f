"""FreeNeRF in JAX: few-shot mip-NeRF with frequency and occlusion regularization."""
