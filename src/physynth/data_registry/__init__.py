"""The SHA-256 of every file of the datasets :mod:`physynth.data` fetches (one ``<name>.txt`` per dataset,
in pooch's registry format; written by ``tools/make_data_registry.py``)."""
