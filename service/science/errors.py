"""Errors that name the request field at fault; the API turns them into 4xx responses."""

from __future__ import annotations


class FieldError(ValueError):
    """Bad input: ``field`` names the request field (or CSV column) at fault, ``message`` says why."""

    status_code = 422

    def __init__(self, field: str, message: str):
        super().__init__(f"{field}: {message}")
        self.field, self.message = field, message
