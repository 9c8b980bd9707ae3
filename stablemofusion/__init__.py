"""stablemofusion: text-to-human-motion generation with the StableMoFusion design."""

__version__ = "0.1.0"
