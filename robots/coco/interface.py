"""CoCo's function interface: the abstract stubs an LLM sees, in two vocabularies.

CoCo has two public vocabularies: the one the GhostShell paper's 30 tasks use
(``paper``) and the one CoCo's deployed firmware exposes (``coco``). Both are
declared here as plain Python stubs (type hints, defaults, ranges as
``annotated_types`` constraints, docstrings) with no implementation. Every stub
names the *behaviour* that implements it (one implementation per behaviour, in
the host) and how its parameters translate: renamed parameters and fixed
arguments. The host binds behaviours to stubs at mount time.

Parameters a stub does not expose take the behaviour's defaults.

One call = one gesture: a repeating behaviour called without ``duration``/``times``
performs one gesture at its natural tempo ("nod three times" is three calls);
``duration`` > 0 repeats it to fill that many seconds, ``times`` repeats it that often.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, Any, Literal

from annotated_types import Interval

from robots.interface import NAME_BYTES, Interface, MaxUtf8Bytes, Name, StubInfo, stub

# --- value vocabularies ---------------------------------------------------------------------

Emotion = Literal[
    "neutral", "smile", "happy", "very_happy", "sad", "very_sad", "angry", "frustrated",
    "very_frustrated", "calm", "surprise", "fear", "very_fear", "pitiable", "wink", "wink_left",
    "wink_right", "sleepy", "shy", "love",
]
EarState = Literal[
    "up", "down", "inquisitive", "relaxed", "alert", "back", "droop",
    # postures real outputs ask for (see robots.coco.motions.EAR_STATES for the angles)
    "flattened", "flat", "flattened_back", "pinned_back", "opponent", "aggressive", "angry",
    "perked", "perked_up", "perk", "raised", "attentive", "listening", "forward",
    "shy", "timid", "curious", "tilted", "sad", "droopy", "sleepy", "tired", "scared", "fear",
    "happy", "neutral", "normal",
]
Direction4 = Literal["forward", "backward", "left", "right"]
Seconds = Annotated[float, Interval(ge=0.0, le=120.0)]
Speed = Annotated[int, Interval(ge=0, le=100)]
Amplitude = Annotated[int, Interval(ge=0, le=100)]
Times = Annotated[int, Interval(ge=1, le=30)]
Volume = Annotated[int, Interval(ge=0, le=100)]
Degrees = Annotated[float, Interval(ge=-720.0, le=720.0)]


#: signed percentage offset from the normal rate (-50: half, 0: normal, 100: double), as cloud TTS APIs take it
RatePercent = Annotated[float, Interval(ge=-50.0, le=100.0)]
#: the voices CoCo's speech engine has; another name falls back to "robot" with a note
VOICES = ("robot", "child", "girl", "boy", "woman", "man", "elder", "narrator")
#: voice emotions of the speech engine
VoiceEmotion = Literal["neutral", "happy", "sad", "angry", "surprise", "fear", "disgust", "excited", "calm",
                       "gentle", "cheerful", "serious", "shy", "tender", "affectionate", "fearful", "surprised"]

CHANNELS: dict[str, str] = {
    "body": "the 8 leg servos (hip swing, knee lift); locomotion and whole-body skills",
    "head": "head yaw and pitch servos",
    "ears": "left and right ear servos",
    "face": "the screen face: expressions and eye animations",
    "speech": "the speaker, for speech (plain text you write is spoken here)",
    "bgm": "background music, mixed under speech",
    "camera": "the head camera",
}


# ============================================================================================
# Paper vocabulary (the 30 grounded HRI tasks)
# ============================================================================================


class PaperFace:
    """Screen face."""

    @stub("face")
    def face_emo(self, emo: Emotion = "happy", duration: Seconds = 2.0) -> None:
        """Show an emotion on the face screen for `duration` seconds (0: until replaced)."""


class PaperHead:
    """Head yaw/pitch."""

    @stub("head")
    def head_act(self, action: Literal["nod", "shake"] = "nod", duration: Seconds = 0.0) -> None:
        """Nod (pitch) or shake (yaw) the head once; with `duration` > 0, repeatedly for that many seconds."""

    @stub("head")
    def head_pose(self, yaw: Annotated[float, Interval(ge=-90.0, le=90.0)] = 0.0,
                  pitch: Annotated[float, Interval(ge=-30.0, le=30.0)] = 0.0) -> None:
        """Turn the head to an absolute pose in degrees; yaw < 0 looks right, yaw > 0 looks left."""


class PaperEars:
    """Ears."""

    @stub("ears")
    def shake_ear(self, duration: Seconds = 0.0) -> None:
        """Flap both ears once; with `duration` > 0, repeatedly for that many seconds."""

    @stub("ears")
    def ear_state(self, state: EarState = "up", duration: Seconds = 1.0) -> None:
        """Hold the ears in a posture ("inquisitive" perks them up, "down" lowers them)."""


class PaperBody:
    """Legs: posture, locomotion and whole-body skills."""

    @stub("body")
    def stand(self, posture: Literal["normal", "forward", "backward"] = "normal") -> None:
        """Stand up; "forward"/"backward" tilt the body that way."""

    @stub("body")
    def sit(self, style: Literal["normal", "dog"] = "normal") -> None:
        """Sit down; "dog" squats on the hind legs like a dog."""

    @stub("body")
    def push_up(self, duration: Seconds = 0.0, times: Times = 1) -> None:
        """Do push-ups: `times` repetitions, or as many as fit in `duration` seconds when it is > 0."""

    @stub("body")
    def wave(self, times: Times = 1) -> None:
        """Wave the front-right leg like a hand, `times` times."""

    @stub("body")
    def chest_expansion_exercise(self, times: Times = 1) -> None:
        """Open and close both front legs like a chest-expansion exercise, `times` times."""

    @stub("body")
    def fly_rub_hands(self, times: Times = 1) -> None:
        """Rub the two front legs together like a fly rubbing its hands, `times` times."""

    @stub("body")
    def body_lean(self, direction: Direction4 = "left", duration: Seconds = 1.0) -> None:
        """Lean (shrug) the body towards `direction` and back."""

    @stub("body")
    def run_distance(self, distance: Annotated[float, Interval(ge=-300.0, le=300.0)] = 20.0) -> None:
        """Walk straight for `distance` centimetres (negative: backwards)."""

    @stub("body")
    def rotate(self, angle: Degrees = 360.0) -> None:
        """Turn in place by `angle` degrees (positive: left/counter-clockwise; negative: right)."""

    @stub("body")
    def move_strides(self, direction: Literal["forward", "backward"] = "forward", times: Times = 1) -> None:
        """Take `times` full walking strides forward or backward."""

    @stub("body", "move_strides", fixed={"direction": "forward"})
    def move_forward(self, times: Times = 1) -> None:
        """Walk forward `times` strides."""

    @stub("body")
    def creep(self, direction: Direction4 = "forward", speed: Speed = 50, duration: Seconds = 0.0) -> None:
        """Creep low to the ground in `direction` at `speed` (0-100): one creeping step cycle, or for `duration` seconds when > 0."""

    @stub("body")
    def wriggle(self, duration: Seconds = 0.0) -> None:
        """Wriggle the whole body once; with `duration` > 0, for that many seconds."""

    @stub("body")
    def single_leg_knock(self, leg: Annotated[int, Interval(ge=1, le=4)] = 1, times: Times = 1) -> None:
        """Tap the ground with one leg: 1 front-right, 2 front-left, 3 back-left, 4 back-right."""

    @stub("body")
    def shake_ass(self, speed: Speed = 50, times: Times = 1) -> None:
        """Wiggle the rear of the body side to side `times` times at `speed` (0-100)."""

    @stub("body")
    def shake_like_dog(self, duration: Seconds = 0.0) -> None:
        """Shake the whole body like a wet dog (one shake; with `duration` > 0, for that many seconds)."""


class PaperAudio:
    """Background music."""

    @stub("bgm")
    def play_bgm(self, duration: Seconds = 5.0, name: Name = "happy", volume: Volume = 60) -> None:
        """Play background music `name` for `duration` seconds (as a parent: until its children finish)."""


class PaperCamera:
    """Head camera."""

    @stub("camera")
    def capture(self) -> None:
        """Take a photo with the head camera; the image is returned as an observation."""


# ============================================================================================
# CoCo's deployed vocabulary
# ============================================================================================


class CocoFace:
    """Screen face."""

    @stub("face", "face_emo", rename={"face": "emo"})
    def display_face(self, face: Emotion = "happy", duration: Seconds = 2.0) -> None:
        """Display a face on the screen for `duration` seconds."""

    @stub("face", "face_emo")
    def emotion(self, emo: Emotion = "happy", duration: Seconds = 2.0) -> None:
        """Express an emotion on the face screen."""

    @stub("face", "face_emo", fixed={"emo": "wink_right"})
    def wink_right(self, duration: Seconds = 1.0) -> None:
        """Wink the right eye."""


class CocoEars:
    """Ears."""

    @stub("ears")
    def ear_state(self, state: EarState = "up", duration: Seconds = 1.0) -> None:
        """Hold the ears in a posture."""

    @stub("ears")
    def ear_swing(self, side: Literal["left", "right"] = "left",
                  start_angle: Annotated[float, Interval(ge=-60.0, le=60.0)] = -30.0,
                  end_angle: Annotated[float, Interval(ge=-60.0, le=60.0)] = 30.0,
                  speed: Speed = 50, duration: Seconds = 0.0) -> None:
        """Swing one ear between two angles (degrees) once; with `duration` > 0, for that many seconds."""

    @stub("ears", "shake_ear")
    def shake_ears(self, duration: Seconds = 0.0) -> None:
        """Flap both ears once; with `duration` > 0, repeatedly for that many seconds."""


class CocoSpeech:
    """Voice settings."""

    @stub("speech")
    def speech_role(self, role: Name = "robot", emotion: VoiceEmotion = "neutral",
                    speech_rate: RatePercent = 0.0, loudness_rate: RatePercent = 0.0) -> None:
        """Set the voice for the following speech: a voice name (robot, child, girl, boy, woman, man, elder,
        narrator; another name falls back to robot), an emotion, and speech rate and loudness as signed
        percentage offsets from normal (-50 = half, 0 = normal, 100 = double)."""


class CocoHead:
    """Head yaw/pitch."""

    head_act = PaperHead.head_act
    head_pose = PaperHead.head_pose


class CocoAudio:
    """Background music."""

    @stub("bgm", "play_bgm")
    def play_bgm(self, name: Name = "happy", volume: Volume = 60) -> None:
        """Play background music `name` (any language) (as a parent: until its children finish)."""


class CocoBody:
    """Legs."""

    @stub("body", "stand")
    def spider_stand(self, posture: Literal["normal", "forward", "backward"] = "normal",
                     duration: Seconds = 1.0) -> None:
        """Stand up in a posture."""

    @stub("body", "sit")
    def spider_sit(self, style: Literal["normal", "dog"] = "normal", duration: Seconds = 1.0) -> None:
        """Sit down."""

    @stub("body", "push_up")
    def spider_push_up(self, duration: Seconds = 0.0) -> None:
        """Do one push-up; with `duration` > 0, push-ups for that many seconds."""

    @stub("body", "run_distance")
    def spider_run_distance(self, speed: Speed = 50, amplitude: Amplitude = 50,
                            distance: Annotated[float, Interval(ge=-300.0, le=300.0)] = 20.0) -> None:
        """Walk `distance` centimetres."""

    @stub("body", "rotate")
    def spider_rotate(self, angle: Degrees = 90.0) -> None:
        """Turn in place by `angle` degrees (positive: left)."""

    @stub("body", "body_lean")
    def spider_body_lean(self, direction: Direction4 = "left", duration: Seconds = 1.0) -> None:
        """Lean the body."""

    @stub("body", "wave")
    def spider_wave_move(self, speed: Speed = 50, amplitude: Amplitude = 50, times: Times = 1) -> None:
        """Wave a front leg."""

    @stub("body", "shake_ass")
    def spider_shake_ass(self, speed: Speed = 50, amplitude: Amplitude = 50, times: Times = 1) -> None:
        """Wiggle the rear of the body."""

    @stub("body", "arm_pull")
    def spider_arm_pull(self, direction: Literal["left", "right", "both", "forward", "backward"] = "both",
                        speed: Speed = 50, times: Times = 1) -> None:
        """Pull the front legs towards the body like pulling a rope (left, right or both legs), `times` times;
        "forward" pulls with both legs towards the body, "backward" pushes both away."""

    @stub("body", "arm_knock")
    def spider_arm_knock(self, speed: Speed = 50, times: Times = 1) -> None:
        """Knock the ground with both front legs in turn."""

    @stub("body", "single_leg_knock")
    def spider_single_leg_knock(self, leg: Annotated[int, Interval(ge=1, le=4)] = 1, speed: Speed = 50,
                                times: Times = 1) -> None:
        """Tap the ground with one leg (1 front-right, 2 front-left, 3 back-left, 4 back-right)."""


PAPER_MODULES: dict[str, type] = {
    "face": PaperFace, "head": PaperHead, "ears": PaperEars, "body": PaperBody,
    "bgm": PaperAudio, "camera": PaperCamera,
}
COCO_MODULES: dict[str, type] = {
    "face": CocoFace, "head": CocoHead, "ears": CocoEars, "speech": CocoSpeech,
    "bgm": CocoAudio, "body": CocoBody,
}
VOCABULARIES: dict[str, dict[str, type]] = {"paper": PAPER_MODULES, "coco": COCO_MODULES}


DEFAULT_VOCABULARY = "paper"

__all__ = ["CHANNELS", "COCO_MODULES", "DEFAULT_VOCABULARY", "MaxUtf8Bytes", "NAME_BYTES", "Name", "PAPER_MODULES",
           "StubInfo", "VOCABULARIES", "VOICES", "stub", "stubs"]


def stubs(vocabulary: str) -> dict[str, tuple[Callable[..., Any], StubInfo]]:
    """All stubs of one of CoCo's own vocabularies: name -> (function, mapping info)."""
    return Interface(VOCABULARIES, DEFAULT_VOCABULARY).stubs(vocabulary)
