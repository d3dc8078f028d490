"""iiwa-ident: identify and tune the joint torque control of a KUKA LBR iiwa."""

__all__ = ["tool_version"]


def tool_version() -> str:
    """The installed package version, recorded in every file the toolkit writes."""
    try:
        from importlib.metadata import version

        return version("iiwa-ident")
    except Exception:  # running from a source tree without installed metadata
        return "0.1.0"
