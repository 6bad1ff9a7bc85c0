"""The Atari games: ALE's ROM ids, their env names, and a clear error when a ROM is missing.

The list is written out (not read from ale-py) so that registering `NaturalAtari/<Game>-v0`
imports nothing heavy; `tests/test_atari.py` checks it against `ale_py.roms.get_all_rom_ids()`.
"""

from __future__ import annotations

import os
from pathlib import Path

from jaxnat.registration import close_matches

__all__ = ["ROM_IDS", "MULTIPLAYER_ONLY", "GAMES", "AUTHORS_GAMES", "game_name", "rom_id", "rom_path",
           "RomNotFoundError"]

# Every ROM that ale-py 0.12 ships (snake_case ids, as `ale_py.roms.get_all_rom_ids()`).
ROM_IDS: tuple[str, ...] = (
    "adventure", "air_raid", "alien", "amidar", "assault", "asterix", "asteroids", "atlantis2",
    "atlantis", "backgammon", "bank_heist", "basic_math", "battle_zone", "beam_rider", "berzerk",
    "blackjack", "bowling", "boxing", "breakout", "carnival", "casino", "centipede",
    "chopper_command", "combat", "crazy_climber", "crossbow", "darkchambers", "defender",
    "demon_attack", "donkey_kong", "double_dunk", "earthworld", "elevator_action", "enduro",
    "entombed", "et", "fishing_derby", "flag_capture", "freeway", "frogger", "frostbite",
    "galaxian", "gopher", "gravitar", "hangman", "haunted_house", "hero", "human_cannonball",
    "ice_hockey", "jamesbond", "journey_escape", "joust", "kaboom", "kangaroo", "keystone_kapers",
    "king_kong", "klax", "koolaid", "krull", "kung_fu_master", "laser_gates", "lost_luggage",
    "mario_bros", "maze_craze", "miniature_golf", "montezuma_revenge", "mr_do", "ms_pacman",
    "name_this_game", "othello", "pacman", "phoenix", "pitfall2", "pitfall", "pong", "pooyan",
    "private_eye", "qbert", "riverraid", "road_runner", "robotank", "seaquest", "sir_lancelot",
    "skiing", "solaris", "space_invaders", "space_war", "star_gunner", "superman", "surround",
    "tennis", "tetris", "tic_tac_toe_3d", "time_pilot", "trondead", "turmoil", "tutankham",
    "up_n_down", "venture", "video_checkers", "video_chess", "video_cube", "video_pinball",
    "warlords", "wizard_of_wor", "word_zapper", "yars_revenge", "zaxxon",
)


# ROMs that ALE runs only in its multi-agent mode: in single-player mode it refuses them by
# ending the whole process (exit code 1, no exception), so they are not registered as envs and
# `rom_id` refuses them with a Python error first.
MULTIPLAYER_ONLY: tuple[str, ...] = ("combat", "joust", "maze_craze", "warlords")


def game_name(rom: str) -> str:
    """ROM id -> env name, as Gymnasium's ALE ids spell it (`space_invaders` -> `SpaceInvaders`)."""
    return rom.title().replace("_", "")


# Env name (`Breakout`) -> ROM id (`breakout`): the games a single agent can play.
GAMES: dict[str, str] = {game_name(r): r for r in ROM_IDS if r not in MULTIPLAYER_ONLY}

# The 16 games of Zhang, Wu and Pineau (2018), table 1.
AUTHORS_GAMES: tuple[str, ...] = (
    "Alien", "AirRaid", "Amidar", "Assault", "Asteroids", "Atlantis", "BeamRider", "Breakout",
    "Carnival", "Centipede", "DemonAttack", "Gravitar", "JourneyEscape", "Phoenix",
    "SpaceInvaders", "StarGunner",
)


class RomNotFoundError(FileNotFoundError):
    """A game's ROM file is not where ale-py looks for it."""


def rom_id(game: str) -> str:
    """`Breakout` (or `breakout`) -> `breakout`; unknown names list the closest games."""
    if game in GAMES:
        return GAMES[game]
    if game in ROM_IDS and game not in MULTIPLAYER_ONLY:
        return game
    if game in MULTIPLAYER_ONLY or game in {game_name(r) for r in MULTIPLAYER_ONLY}:
        raise ValueError(f"{game} is a multiplayer-only ROM: ALE runs it only in its multi-agent mode, "
                         "which Natural Atari does not offer (single-agent games: jaxnat.atari.GAMES)")
    close = close_matches(game, GAMES)
    hint = f" Did you mean: {', '.join(close)}?" if close else ""
    raise ValueError(
        f"Unknown Atari game {game!r}.{hint} Games are ALE's ROMs in CamelCase "
        f"(jaxnat.atari.GAMES lists all {len(GAMES)})."
    )


def rom_path(game: str) -> Path:
    """Path of `game`'s ROM, checked by ale-py against its md5 list; a clear error if missing."""
    rom = rom_id(game)
    from ale_py import roms  # noqa: PLC0415  (ale-py is optional; imported when a game is built)

    where = os.environ.get("ALE_ROMS_DIR") or str(Path(roms.__file__).parent)
    try:
        path = roms.get_rom_path(rom)
    except FileNotFoundError:
        path = None
    if path is None or not Path(path).is_file():
        raise RomNotFoundError(
            f"The ROM of {game!r} ({rom}.bin) is missing from {where}. ale-py>=0.9 ships the "
            "ROMs: reinstall it (pip install --force-reinstall 'jaxnat[atari]'), or point "
            f"ALE_ROMS_DIR at a folder holding {rom}.bin."
        )
    return Path(path)
