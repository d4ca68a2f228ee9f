"""Loss terms: reconstruction, occlusion (FreeNeRF), depth smoothness (RegNeRF)."""
