"""Map bundles: rasterised, versioned cities built from ingested tables, and the API to read them.

``dataset.catalog`` lists what is on disk; ``dataset.cli`` is the ``uavdata``
command. The RL and eval packages read cities through this package only.
"""
