"""The ``skyloc`` console command: one click group, each package registers its subcommands."""
__version__ = "0.1.0"
