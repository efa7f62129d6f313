"""The bad-input corpus: every way a user or an attacker has fed the CLIs something wrong (see ``cases.py``)."""
