"""Ingest Ricoh Theta cards: metadata, dual-fisheye unwarping, HDR merging (see the Capture issue)."""
