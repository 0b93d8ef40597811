"""Reading one JSON file of the release, with errors that name the file."""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from pedx_graph.data.types import DataFormatError


def read_json_file(path: str | os.PathLike) -> Any:
    """The parsed content of ``path``; :class:`DataFormatError` naming the file when it cannot be read or
    is not valid JSON (field ``<json>``)."""
    path = Path(path)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise DataFormatError(path, None, f"cannot read file ({exc.strerror or exc})") from exc
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DataFormatError(path, "<json>", f"malformed JSON ({exc})") from exc
    except ValueError as exc:       # an integer literal longer than Python's int conversion limit
        raise DataFormatError(path, "<json>", "malformed JSON (a number literal is too long)") from exc
    except RecursionError as exc:
        raise DataFormatError(path, "<json>", "malformed JSON (arrays or objects nested too deeply)") from exc
