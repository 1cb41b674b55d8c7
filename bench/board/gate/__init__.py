"""The CI regression gate (`bench regress`): its inputs checked, pairs matched, sequential tests, budget, outputs.

`inputs` (candidate and baseline arguments checked before anything runs), `pairs` (records matched by
cell and seed), `sequential` (the paired tests pooled, per split and per cell, alpha spent over looks),
`power` (episodes per cell for a stated power), `outputs` (terminal tables, JUnit XML, Markdown),
`unpaired` (runs with other seeds: exact unconditional tests per cell, one look; `paired=false`).
"""
