"""pvo_tools: the `pvo` command and its I/O: converters, bag play/record, graph inspection."""

__version__ = "0.1.0"
