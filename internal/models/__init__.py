"""The model: encodings, Gaussians, sampling, volume rendering, MLP, frequency masks, precision."""
