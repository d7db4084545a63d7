"""Command-line interfaces: ``neuenh`` (local work) and, later, ``neuenh-client``."""
