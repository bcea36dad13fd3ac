"""fastdet's version: one definition, read by the package, the build and the kernel cache key."""

__version__ = "0.2.0"
