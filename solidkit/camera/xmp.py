"""The GPano fields of an XMP packet (Google, *Photo Sphere XMP metadata*), with the standard library's XML parser."""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from typing import Any

__all__ = ["GPANO_NS", "XMP_APP1", "parse_gpano"]

GPANO_NS = "http://ns.google.com/photos/1.0/panorama/"
#: The APP1 segment header of an XMP packet in a JPEG.
XMP_APP1 = b"http://ns.adobe.com/xap/1.0/\x00"


def parse_gpano(packet: bytes, warnings: list[str]) -> dict[str, Any]:
    """GPano fields of an XMP packet, as attributes or elements; numbers converted."""
    start = packet.find(b"<x:xmpmeta")
    end = packet.find(b"</x:xmpmeta>")
    if start < 0 or end < 0:
        start, end = packet.find(b"<rdf:RDF"), packet.find(b"</rdf:RDF>")
        if start < 0 or end < 0:
            warnings.append("xmp_unparsable: no xmpmeta element")
            return {}
        end += len(b"</rdf:RDF>")
    else:
        end += len(b"</x:xmpmeta>")
    try:
        root = ET.fromstring(packet[start:end])
    except ET.ParseError as exc:
        warnings.append(f"xmp_unparsable: {exc}")
        return {}
    out: dict[str, Any] = {}
    prefix = "{" + GPANO_NS + "}"
    for el in root.iter():
        for key, val in el.attrib.items():
            if key.startswith(prefix):
                out[key[len(prefix) :]] = val
        if isinstance(el.tag, str) and el.tag.startswith(prefix) and el.text is not None:
            out[el.tag[len(prefix) :]] = el.text.strip()
    for key, val in list(out.items()):
        if val.lower() in ("true", "false"):
            out[key] = val.lower() == "true"
            continue
        try:
            num = float(val)
        except ValueError:
            continue
        if not math.isfinite(num):
            warnings.append(f"gpano_bad_value: {key}={val!r}")
            del out[key]
            continue
        out[key] = int(num) if re.fullmatch(r"[+-]?\d+", val) else num
    return out
