"""Output folders and files that never cost a user a file.

A run is written into a staging folder beside its destination and put in place only when complete, in one step
(``jaxdip.outdir.swap``). Every folder jaxdip writes holds a marker (``.jaxdip.json``, ``jaxdip.outdir.marker``)
naming the experiment and each file it wrote with its SHA-256, so a later run can tell its own output from the
user's (``jaxdip.outdir.folder``):

- a destination that does not exist, or an empty folder, is written;
- a previous run of the same experiment is replaced when every entry in it is a file the marker lists with
  unchanged content;
- a jaxdip folder of another experiment is replaced only with ``force``;
- anything else (a file, a link, a folder without a valid marker, a folder where the user added or edited a
  file) is refused with one line.

``prepare`` runs every check and creates the staging folder before any simulation is compiled, so a
destination that cannot be written is reported in seconds, not after the run (``jaxdip.outdir.staging``).
"""

from jaxdip.outdir.files import check_file, umask, write_file_atomic
from jaxdip.outdir.folder import OutputError, Verdict, shown
from jaxdip.outdir.marker import MARKER, NotOurs
from jaxdip.outdir.staging import Staging, check_destination, prepare

__all__ = ["MARKER", "NotOurs", "OutputError", "Staging", "Verdict", "check_destination", "check_file", "prepare", "shown",
           "umask", "write_file_atomic"]
