"""Flight-log readers (one module per format) returning a common ``FlightLog``."""
