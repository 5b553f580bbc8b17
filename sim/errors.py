"""Errors that name what is wrong: the field, the value given and the limit it breaks."""


class FieldError(ValueError):
    """An input refused with ``field``, ``value`` and ``limit`` (what is allowed); str() is the full message."""

    def __init__(self, field: str, value, limit: str, message: str):
        super().__init__(message)
        self.field = field
        self.value = value
        self.limit = limit

    def __reduce__(self):
        """Pickled as its class, message and attributes, so that one raised in a worker process (sim.engine
        run_batch, the campaign's pool) reaches the caller as itself: an exception's default pickling calls the
        class with its message alone, which this ``__init__`` (and its subclasses' own) refuses, and the pool
        then reported a worker "terminated abruptly" instead of the refusal's words."""
        return rebuilt_exception, (type(self), self.args, dict(self.__dict__))


def rebuilt_exception(kind: type, args: tuple, state: dict) -> BaseException:
    """An exception of class ``kind`` from its ``args`` and attributes, without calling its ``__init__`` (whose
    arguments may be others than its message): FieldError's pickling, and the service's check pool
    (backend.checks), which hands back what a worker raised."""
    error = kind.__new__(kind)
    Exception.__init__(error, *args)
    error.__dict__.update(state)
    return error
