"""The command line's output options under the output rule (``common.output_path``): ``-o``,
``--plots``, ``--log-folder`` and ``--xcp-a2l``, checked before any work by what each names."""

from __future__ import annotations

from smartjoint.common import figures, output_path

# The commands whose -o names a folder (rig with --campaign too); every other -o names a file.
_FOLDER_OUTPUTS = ("run", "codegen", "sweep")


def check_outputs(args) -> None:
    """The output rule (`common.output_path`) on -o and --plots before any work: a file where a
    file is meant, a folder where a folder is, never a link, FIFO, device or a path below a file;
    a plots folder holds only PNGs. Which entries of an output folder are its own each command
    decides (run: its manifest, codegen: its banners, sweep: its batches)."""
    if getattr(args, "output", None):
        if args.command in _FOLDER_OUTPUTS or (args.command == "rig" and args.campaign):
            output_path.check_folder(args.output, "-o", ours=lambda entry: True)
        else:
            output_path.check_file(args.output, "-o")
    if getattr(args, "plots", None):
        output_path.check_folder(args.plots, "--plots", ours=figures.is_figure)
    if getattr(args, "log_folder", None):  # sil: sil_<law>.blf and xcp_sil_<law>.blf, replaced by name
        output_path.check_folder(args.log_folder, "--log-folder", ours=lambda entry: entry.suffix == ".blf")
    if getattr(args, "xcp_a2l", None):
        output_path.check_file(args.xcp_a2l, "--xcp-a2l")


__all__ = ["check_outputs"]
