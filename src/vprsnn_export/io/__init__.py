"""The project's files: the float checkpoint, atomic writes and the npz+JSON container, the generic dataclass <-> JSON mapping."""
