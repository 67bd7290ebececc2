"""Counting whole orchard rows: cut into overlapping segments trained one by one (or as Ray jobs), joined into one
count per tree, georeferenced for farm software (``fruitnerfpp orchard``, the fruit_counter's row mode).

Modules: ``config`` (OrchardConfig), ``row_frame`` (row coordinates, what a camera sees), ``segments`` (the cut,
segment datasets), ``jobs`` (one segment: train, export, count; the in-process and Ray runners), ``merge`` (every
fruit once), ``trees`` (planting map or found from the fruit; nearest crown), ``geodesy`` + ``gnss`` + ``georef``
(world frame <-> WGS84), ``report`` (trees.csv, GeoJSON, report v2), ``row_run`` (the whole offline row),
``evaluation`` (against a synthetic row's ground truth).

Nothing here starts Ray or changes process-wide state: the caller (CLI, node) owns the Ray instance and threads.
"""
