"""MCAP files: the reader that checks every CRC, the streaming writer, record layouts, whole-file operations."""
