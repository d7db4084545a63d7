"""neuenh: neural enhancement of analytical appearance models (the science package).

torch and numpy only: no HTTP, no Ray, no SQL (ARCHITECTURE §2).
"""

__version__ = "0.1.0"
