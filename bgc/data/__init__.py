"""Data as people have them, mapped once at the edge: recorded runs read
and written (``runs``: the CSV), and rows placed on the model's time grid one
sample at a time (``sampler``: gaps, held inputs, missing sensors). The rest
of the code sees one kind of run; ``clock`` writes its times back as people
read them (a run of absolute times, as ISO 8601 timestamps)."""
