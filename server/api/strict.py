"""The base of every REST request body: bad input gets a 422 naming it, never a 500 later.

It refuses bodies that parse but would break something downstream: ``NaN``/``Infinity`` (Python's
JSON reader accepts them) in numbers, and lone surrogates (``"\\ud800"``, legal JSON but not
encodable as UTF-8) in text, which would make SQLite and the JSON response fail after the drone had
already been told to move.
"""

from __future__ import annotations

import math
from typing import Any

from fastapi import FastAPI, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel, ConfigDict, model_validator


def find_surrogate(value: Any, path: str = "") -> str | None:
    """The path of the first string in ``value`` (nested dicts/lists) that is not valid
    Unicode text (a lone surrogate), or None."""
    if isinstance(value, str):
        try:
            value.encode("utf-8")
        except UnicodeEncodeError:
            return path or "body"
        return None
    if isinstance(value, dict):
        for k, v in value.items():
            found = find_surrogate(k, path) or find_surrogate(v, f"{path}.{k}" if path else str(k))
            if found:
                return found
    if isinstance(value, list | tuple):
        for i, v in enumerate(value):
            found = find_surrogate(v, f"{path}[{i}]")
            if found:
                return found
    return None


class StrictBody(BaseModel):
    """Unknown fields, non-finite numbers and lone surrogates are refused (422)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    @model_validator(mode="before")
    @classmethod
    def _valid_text(cls, data: Any) -> Any:
        where = find_surrogate(data)
        if where is not None:
            raise ValueError(
                f"{where}: text contains a lone surrogate (not valid Unicode); send UTF-8 text"
            )
        return data


def json_safe(value: Any) -> Any:
    """``value`` with what JSON cannot carry made printable: non-finite floats as strings,
    lone surrogates escaped (``"\\ud800"``). Validation errors echo the bad input back; without
    this, echoing a NaN or a surrogate turned a 422 into a 500."""
    if isinstance(value, float):
        return value if math.isfinite(value) else repr(value)
    if isinstance(value, str):
        return value.encode("utf-8", "backslashreplace").decode("utf-8")
    if isinstance(value, dict):
        return {json_safe(str(k)): json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    if value is None or isinstance(value, bool | int):
        return value
    return json_safe(str(value))


async def validation_error_handler(request: Request, exc: Exception) -> JSONResponse:
    """FastAPI's 422 for a request that does not validate, safe for any input."""
    errors = exc.errors() if isinstance(exc, RequestValidationError) else [str(exc)]
    return JSONResponse(status_code=422, content={"detail": json_safe(jsonable_encoder(errors))})


def install(app: FastAPI) -> None:
    """Register :func:`validation_error_handler` on ``app``."""
    app.add_exception_handler(RequestValidationError, validation_error_handler)
