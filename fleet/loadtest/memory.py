"""This process's resident memory, for the soak's samples and the set-up's progress lines."""

from __future__ import annotations


def rss_mb() -> float:
    """This process's resident set size now (MB); the peak (``ru_maxrss``) where ``/proc`` is missing."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


__all__ = ["rss_mb"]
