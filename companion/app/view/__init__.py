"""`uavsearch view`: a live map of a flying swarm, or a replay of a finished run, in the browser.

`scene` builds what does not change (region, grid, prior, CVT), `frames` the state of one step,
`live` listens to a mission's mesh (read-only), `replay` loads a run's output directory, and
`server` serves the page (package data under `static/`) and streams frames over a websocket.
See docs/view.md.
"""
