"""Evaluation: rendering whole images, metrics, LPIPS, depth errors, outputs, videos."""
