"""Measurement: one module per ``wholehand bench`` command (``allocate``, ``contacts``,
``cycle`` with its ``worst_case`` replay and ``estimate`` breakdown, ``soak``, ``thin_walls``,
``hw``, ``pipeline``), each a function that returns a JSON-ready result. Percentiles come from
:mod:`wholehand.timing`; the product's own code imports nothing from here."""
