"""bayestouch: probabilistic inference for tactile shape and texture sensing."""
__version__ = "0.1.0"
