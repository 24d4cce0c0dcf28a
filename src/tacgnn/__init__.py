"""tacgnn: tactile in-hand manipulation with a blind robot hand."""
__version__ = "0.1.0"
