"""skyloc ground segment: skyline-database renderers and the render service."""
__version__ = "0.1.0"
