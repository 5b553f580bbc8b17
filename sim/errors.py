"""Errors that name what is wrong: the field, the value given and the limit it breaks."""


class FieldError(ValueError):
    """An input refused with ``field``, ``value`` and ``limit`` (what is allowed); str() is the full message."""

    def __init__(self, field: str, value, limit: str, message: str):
        super().__init__(message)
        self.field = field
        self.value = value
        self.limit = limit
