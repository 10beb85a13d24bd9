"""SOLID-Img-style synthetic data and a virtual field campaign (Mitsuba 3)."""
