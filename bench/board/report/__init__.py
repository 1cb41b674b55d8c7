"""`bench report`: a static HTML page of a run, a leaderboard, a calibration or a gate verdict.

`page` (the sections and the page), `figures` (matplotlib figures), `html` (escaping, tables, images,
estimates with intervals), `remote` (a remote policy's round-trip latency).
"""
