"""Which object is this: the paper's classification experiment and the shipped classifier.

``network`` (PointNet with a transformer in front), ``data`` (labelled partial views),
``train`` (one row), ``experiment`` (the whole table), ``report`` (table, per-class, confusion).
"""
