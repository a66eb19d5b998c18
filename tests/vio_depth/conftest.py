"""The sample fixtures (``mini_street``, ``digest``) live in ``tests/conftest.py``, shared with
``tests/robustness``."""
