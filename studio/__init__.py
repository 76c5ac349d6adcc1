"""MimicKit Studio: the web studio (FastAPI + viser) on top of the `mimickit` library.

Layers: `studio` imports `mimickit`; `mimickit` never imports `studio`, `fastapi` or `viser`.
"""
