"""``svss view``: the operator's live web page (:mod:`.server`, :mod:`.render`,
``static/``). See docs/operator.md, "svss view"."""
