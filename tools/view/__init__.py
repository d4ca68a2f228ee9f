"""tools.view: a web viewer of trained runs (viser), `python -m tools.view`.

cameras.py (viser's cameras, rays of any camera), resolution.py (frame sizes), layout.py (two runs in one frame),
frames.py (one frame), runs.py (a loaded run), service.py (a browser's render thread), watch.py (newer
checkpoints), scene.py (cameras, path, points), panel.py (the GUI), app.py (the server), __main__.py (the command);
screenshot.py: a screenshot of a viewer's page in headless Chromium (the browser test, docs/viewer.png).
"""
