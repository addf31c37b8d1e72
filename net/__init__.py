"""Networking: Zenoh bus, message schemas (msgpack, validated), channel emulation."""
