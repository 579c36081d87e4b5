"""Readers and writers for the formats skyrecon users already have. See DESIGN.md (Formats)."""
