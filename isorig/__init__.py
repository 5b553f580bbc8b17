"""isorig application wiring: the command line. Numerics live in sim/, the service in backend/."""
