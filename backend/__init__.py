"""isorig backend: the FastAPI service that runs rig tests in a worker process, streams them and stores them."""
