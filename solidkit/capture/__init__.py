"""Ingest Ricoh Theta cards: metadata, dual-fisheye unwarping, HDR merging."""
