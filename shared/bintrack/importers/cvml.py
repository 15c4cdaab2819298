"""Ground truth in CVML XML (List et al., "CVML — an XML-based computer vision markup
language", ICPR 2004), the interchange format of many annotated people datasets:
``<frame number="N">`` holding ``<object id="K">`` each with a ``<box xc= yc= w= h=/>``. The box
centre is the person's position, in units of ``scale`` × the given length unit; frame N is at
event time (N − first)·period s, with ``first`` the number of the matrix's first row (1).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

from bintrack.formats import FormatError, TruthRow


def read_cvml(path: Path | str, period: float, scale: float = 1.0, first_frame: int = 1) -> list[TruthRow]:
    """truth.csv rows from the CVML file at ``path``: target = object id, position = box centre
    × ``scale`` (metres per CVML unit), t = (frame − ``first_frame``)·``period`` s. Rows come
    sorted by (target, t); a frame before ``first_frame`` is an error."""
    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except OSError as exc:
        raise FormatError(path, None, "file", exc.strerror or str(exc)) from None
    except ET.ParseError as exc:
        raise FormatError(path, exc.position[0], "xml", str(exc).split(":")[0]) from None
    rows: list[TruthRow] = []
    frames = root.iter("frame")
    for frame in frames:
        try:
            number = int(frame.get("number", ""))
        except ValueError:
            raise FormatError(path, None, "frame.number", f"not a whole number: {frame.get('number')!r}") from None
        if number < first_frame:
            raise FormatError(path, None, "frame.number", f"frame {number} is before the first frame {first_frame}")
        t = round((number - first_frame) * period, 9)
        seen: set[str] = set()
        for obj in frame.iter("object"):
            target = (obj.get("id") or "").strip()
            if not target or "," in target:
                raise FormatError(path, None, "object.id", f"frame {number}: missing or bad object id {target!r}")
            if target in seen:
                raise FormatError(path, None, "object.id", f"frame {number}: object {target} appears twice")
            seen.add(target)
            box = obj.find("box")
            if box is None:
                raise FormatError(path, None, "box", f"frame {number}, object {target}: no <box>")
            try:
                xc, yc = float(box.get("xc", "")), float(box.get("yc", ""))
            except ValueError:
                raise FormatError(path, None, "box", f"frame {number}, object {target}: xc/yc not numbers") from None
            if not (math.isfinite(xc) and math.isfinite(yc)):
                raise FormatError(path, None, "box", f"frame {number}, object {target}: xc/yc not finite")
            rows.append(TruthRow(t, target, xc * scale, yc * scale))
    if not rows and not any(True for _ in root.iter("frame")):
        raise FormatError(path, None, "frame", "no <frame> elements: not CVML ground truth")
    rows.sort(key=lambda r: (r.target, r.t))
    return rows
