"""
Which sb3-icrl algorithm saved a model zip, so that ``load`` refuses another algorithm's model with a clear error
instead of rebuilding it as the wrong class (or failing on a missing key deep inside SB3).
"""

import io
import os
import pathlib
import re
import zipfile
import zlib
from typing import Any, TypeVar

import torch as th
from stable_baselines3.common.save_util import json_to_data, load_from_zip_file, open_path
from stable_baselines3.common.type_aliases import GymEnv

#: The key of a zip's ``data`` that names the sb3-icrl algorithm that saved it (older zips are told by their content)
SAVED_ALGORITHM_KEY = "sb3_icrl_algorithm"
# Bases shared by several algorithms: never the algorithm a model is
_SHARED_BASES = ("CheckedLoadMixin", "ICRLAlgorithmMixin", "LagrangianICRL")
# Modules of classes that fit an algorithm to another tool (rl_zoo3's ZooGACL...): the model is the algorithm's
_ADAPTER_MODULES = ("sb3_icrl.zoo.rl_zoo3",)
#: Prefix of the rl_zoo3 adapters' names, which zips they saved recorded before they were told apart
_ADAPTER_PREFIX = "Zoo"
#: The default trainer of each ICRL algorithm that saved zips before they recorded :data:`SAVED_ALGORITHM_KEY`, by
#: qualified name: such a zip is told by the closest of them in its trainer's bases (zips saved since name themselves)
UNRECORDED_TRAINERS = {
    "sb3_icrl.gacl.gacl.GACLTrainer": "GACL",
    "sb3_icrl.bc2l.bc2l.BC2LTrainer": "BC2L",
    "sb3_icrl.mecl.mecl.MECLTrainer": "MECL",
    "sb3_icrl.vicrl.vicrl.VICRLTrainer": "VICRL",
}


def library_algorithm(algorithm_class: type) -> str:
    """
    The sb3-icrl algorithm a class is (a user's subclass of ``VICRL`` is a ``VICRL``).

    :param algorithm_class: An algorithm class
    :return: The name of the first sb3-icrl class in its method resolution order (its own name when there is none)
    """
    for base in algorithm_class.__mro__:
        own = base.__module__.startswith("sb3_icrl.") and base.__module__ not in _ADAPTER_MODULES
        if own and base.__name__ not in _SHARED_BASES:
            return base.__name__
    return algorithm_class.__name__


def saved_algorithm(data: dict[str, Any]) -> str | None:
    """
    The sb3-icrl algorithm that saved a zip's ``data``: the name it recorded, else what it holds (ICRL models: their
    constraint model and trainer class; PPO-Lagrangian: its multiplier).

    :param data: The ``data`` part of an SB3 zip
    :return: ``"PPOLagrangian"``, ``"GACL"``, ``"BC2L"``, ``"MECL"``, ``"VICRL"``, or ``None`` when the zip was not saved
        by an sb3-icrl algorithm (a plain stable-baselines3 model)
    """
    recorded = data.get(SAVED_ALGORITHM_KEY)
    if isinstance(recorded, str):
        return recorded.removeprefix(_ADAPTER_PREFIX)
    if "constraint_net_spec_" in data:
        trainer = data.get("trainer_class")
        if not isinstance(trainer, type):
            return None
        bases = (f"{base.__module__}.{base.__qualname__}" for base in trainer.__mro__)
        return next((UNRECORDED_TRAINERS[name] for name in bases if name in UNRECORDED_TRAINERS), None)
    if "lagrange_multiplier" in data:
        return "PPOLagrangian"
    return None


def read_saved_data_text(path: str | pathlib.Path | io.BufferedIOBase) -> str | None:
    """
    The ``data`` entry of an SB3 model zip as JSON text, without unpickling anything, or ``None`` when the zip cannot
    be read or has no such entry. A file object given is left where it was (SB3 reads it again).

    :param path: A model zip (path, or file object open for reading)
    :return: The entry's text
    """
    try:
        file = open_path(path, "r", verbose=0, suffix="zip")
    except (OSError, ValueError):
        return None
    start = file.tell()
    try:
        with zipfile.ZipFile(file) as archive:
            if "data" not in archive.namelist():
                return None
            return archive.read("data").decode()
    except (zipfile.BadZipFile, UnicodeDecodeError, OSError):
        return None
    finally:
        if isinstance(path, (str, pathlib.Path)):
            file.close()
        else:
            file.seek(start)


def _read_data(path: str | pathlib.Path | io.BufferedIOBase, custom_objects: dict[str, Any] | None) -> dict[str, Any] | None:
    """The ``data`` of an SB3 zip, or ``None`` when it cannot be read (SB3's own ``load`` then says why)."""
    text = read_saved_data_text(path)
    if text is None:
        return None
    try:
        return json_to_data(text, custom_objects=custom_objects)
    except ValueError:
        return None


def check_saved_algorithm(
    algorithm_class: type, path: str | pathlib.Path | io.BufferedIOBase, custom_objects: dict[str, Any] | None = None
) -> None:
    """
    Fail clearly when ``path`` holds a model that another algorithm saved.

    :param algorithm_class: The class whose ``load`` was called
    :param path: The zip (a path or a file object)
    :param custom_objects: As for ``load``
    :raises ValueError: When the zip was saved by another sb3-icrl algorithm, or by none
    """
    data = _read_data(path, custom_objects)
    if data is None:
        return
    expected = library_algorithm(algorithm_class)
    found = saved_algorithm(data)
    where = repr(os.fspath(path)) if isinstance(path, (str, pathlib.Path)) else "The file"
    if found is None:
        raise ValueError(
            f"{where} was not saved by an sb3-icrl algorithm (it holds neither a Lagrange multiplier nor a constraint "
            f"model), so {algorithm_class.__name__}.load cannot rebuild it: load it with the stable-baselines3 class that "
            "saved it."
        )
    if found != expected:
        raise ValueError(
            f"{where} holds a {found} model, not a {expected} one: load it with {found}.load(...) instead of "
            f"{algorithm_class.__name__}.load(...)."
        )


SelfCheckedLoad = TypeVar("SelfCheckedLoad", bound="CheckedLoadMixin")


class CheckedLoadMixin:
    """
    SB3's ``load`` behind :func:`check_saved_algorithm`; listed before the SB3 algorithm in the bases
    (``class PPOLagrangian(CheckedLoadMixin, PPO)``), so that its ``load`` runs first.
    """

    @classmethod
    def load(
        cls: type[SelfCheckedLoad],
        path: str | pathlib.Path | io.BufferedIOBase,
        env: GymEnv | None = None,
        device: th.device | str = "auto",
        custom_objects: dict[str, Any] | None = None,
        print_system_info: bool = False,
        force_reset: bool = True,
        **kwargs: Any,
    ) -> SelfCheckedLoad:
        """SB3's ``load``, refusing a zip that another algorithm saved (with a message naming both)."""
        check_saved_algorithm(cls, path, custom_objects)
        return super().load(path, env, device, custom_objects, print_system_info, force_reset, **kwargs)  # type: ignore[misc]


def model_damage(path: str, load: bool = True) -> str | None:
    """
    What is wrong with a saved model file, told before SB3 loads it (whose own errors name neither the file nor the
    cause): empty, not a zip, cut short, or with an entry that does not unpack.

    Without ``load``, each entry is read (its checksum checked) and each ``.pth`` entry's own archive directory is
    opened, with no torch object built: as quick as ``ZipFile.testzip`` (about 1 ms for a 1.7 MB HalfCheetah model),
    and it finds a tensor entry cut short inside a zip that is whole.

    :param path: A ``.zip`` saved by stable-baselines3
    :param load: Also unpack its entries (``data`` and the ``.pth`` tensors): a zip can be whole and still hold a
        broken entry
    :return: ``None`` when it reads, else what is wrong (a phrase that follows the file's name)
    """
    if os.path.getsize(path) == 0:
        return "is empty (0 bytes)"
    if not zipfile.is_zipfile(path):
        return "is not a zip archive"
    try:
        with zipfile.ZipFile(path) as archive:
            names = archive.namelist()
            if "data" not in names:
                # A copy cut short: what zipfile then reads is the last archive stored inside it (a .pth)
                return "is cut short or damaged (it has no `data` entry)"
            for name in names:
                try:
                    content = archive.read(name)
                except zipfile.BadZipFile:  # zipfile checks each entry's CRC as it reads it
                    return f"is damaged (its entry {name!r} fails its checksum)"
                except zlib.error as error:
                    return f"is damaged (its entry {name!r} does not decompress: {error})"
                if name.endswith(".pth") and not _whole_torch_archive(content):
                    return f"is damaged (its tensor entry {name!r} is cut short or is not a torch archive)"
    except (zipfile.BadZipFile, OSError, EOFError) as error:
        return f"is cut short or damaged ({error})"
    if load:
        try:
            load_from_zip_file(path, device="cpu")
        except Exception as error:  # a broken JSON, pickle or tensor entry
            return f"is damaged ({first_sentence(error)})"
    return None


def _whole_torch_archive(content: bytes) -> bool:
    """
    Whether the bytes of a ``.pth`` entry hold a whole ``torch.save`` archive: a zip whose directory (at its end)
    reads and that has its ``data.pkl``. Tensors saved in torch's legacy format (a pickle, not a zip) are not told.

    :param content: The entry's bytes
    """
    if not content:
        return False
    if not content.startswith(b"PK"):
        return True  # the legacy format, which only torch.load can check
    try:
        with zipfile.ZipFile(io.BytesIO(content)) as archive:
            return any(name.endswith("data.pkl") for name in archive.namelist())
    except (zipfile.BadZipFile, EOFError, ValueError):
        return False


def first_sentence(error: BaseException) -> str:
    """``error``'s type and the first sentence of its message (torch's go on for a paragraph)."""
    text = re.split(r"(?<=\.)\s", str(error).strip(), maxsplit=1)[0]
    return f"{type(error).__name__}: {text}" if text else type(error).__name__
