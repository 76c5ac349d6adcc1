"""The hostile-input suite: crafted `.pkl`, `.pt`, yaml, arg files and HTTP requests.

Every case is a parametrized test whose id says the outcome it expects: `err-...` (one clear
`MimicKitError` line, or an HTTP 4xx whose body is a readable message) or `ok-...` (accepted as
valid). `pytest tests/hostile --collect-only -q` therefore counts the suite by outcome.
"""
