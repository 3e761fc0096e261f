"""Files: contact-point CSVs (:mod:`.contacts`), atomic JSON/CSV/text writers (:mod:`.files`), netCDF recordings
(:mod:`.recording`), device files (:mod:`.device_file`) and meshes with a per-vertex spread (:mod:`.meshes`)."""

from bayestouch.io.contacts import ContactPoints, load_contact_points, save_contact_points
from bayestouch.io.files import read_csv_rows, write_csv_rows, write_json, write_text
from bayestouch.io.meshes import read_spread_mesh, write_spread_mesh
from bayestouch.io.recording import build_dataset, read_recording, write_recording

__all__ = [
    "ContactPoints",
    "load_contact_points",
    "save_contact_points",
    "read_csv_rows",
    "write_csv_rows",
    "write_json",
    "write_text",
    "build_dataset",
    "read_recording",
    "write_recording",
    "read_spread_mesh",
    "write_spread_mesh",
]
