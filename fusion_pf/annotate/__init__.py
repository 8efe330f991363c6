"""Multi-operator web annotation of palm centres (paper 003 §4.1 reference).

``fusion-pf annotate REC.mcap --db annotations.sqlite`` serves a local web page
(:mod:`.server`) where operators click the palm centre of every frame; clicks
go to SQLite (:mod:`.db`). ``fusion-pf annotations export`` writes the per-frame
reference (operator mean and spread) and the per-operator agreement as CSV;
the scorer reads the reference with :func:`.db.reference_table`.
"""
