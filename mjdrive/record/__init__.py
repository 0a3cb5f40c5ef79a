"""Episode logs: one MCAP file per episode with Foxglove schemas, and reading them back.

    from mjdrive.record import RecordEpisodes, RecordOptions
    env = RecordEpisodes(gymnasium.make("mjdrive/Waypoints-Straight-v0"), "runs/logs",
                         RecordOptions(camera_every=1))

See `recorder.py` for file names and topics, `reader.py` to read files back; `mjdrive.envs.replay` re-simulates
them.
"""

from pathlib import Path

from mjdrive.record.recorder import EnvSpec, EpisodeRecorder, RecordOptions, episode_filename
from mjdrive.record.wrappers import RecordedEnvironment, RecordEpisodes, load

LAYOUT = Path(__file__).resolve().parents[1] / "layouts" / "mjdrive.json"  # Foxglove layout for the logs

__all__ = ["LAYOUT", "EnvSpec", "EpisodeRecorder", "RecordOptions", "RecordEpisodes", "RecordedEnvironment",
           "episode_filename", "load"]
