"""Foreign actions: verb phrasings of things the Bandai-Namco corpus has none of, as training negatives for
the out-of-domain detector (:mod:`.domain`).

:func:`foreign_captions` fills the corpus caption grammar (:mod:`stablemofusion.data.captions`: the same
sentence structures, subjects, style words, irrelevant details and typos as the training captions) with
these phrasings in place of a content's, so that a classifier trained on training captions against them can
only tell the two apart by the action. The phrasings were written for training the detector and avoid the
activities of ``benchmarks/ood_heldout.txt`` and ``benchmarks/ood_calibration.txt`` (the held-out foreign
prompts the detector is calibrated and reported on) and motions the corpus has (walks, kicks, punches,
waves, hailing someone, nodding a bow).
"""

from __future__ import annotations

import random
import zlib

FOREIGN_PHRASES: tuple[str, ...] = (
    '<swim|swims|swimming> freestyle',
    '<swim|swims|swimming> laps in the pool',
    '<do> the backstroke',
    '<float> on {pos} back in the water',
    '<paddle> a canoe',
    '<water-ski> behind a boat',
    '<snorkel> in the sea',
    '<climb> a tree',
    '<climb> a mountain',
    '<sit|sits|sitting> on the ground',
    '<sit|sits|sitting> on a chair and <cross> {pos} legs',
    '<lie|lies|lying> on {pos} stomach',
    '<lie|lies|lying> on the grass',
    '<stand> up from a chair',
    '<get|gets|getting> up off the ground',
    '<kneel> on one knee',
    '<kneel> on the floor',
    '<squat> down',
    '<crouch> low to the ground',
    '<crawl> forward on {pos} belly',
    '<roll> over on the floor',
    '<roll> down a hill',
    '<fall> down',
    '<trip> and <fall> forward',
    '<faint> and <collapse>',
    '<jump> forward with both feet',
    '<jump> over an obstacle',
    '<do> a long jump',
    '<do> a high jump',
    '<hop> on one leg',
    '<jump> on a trampoline',
    '<do> a somersault',
    '<do> a front handspring',
    '<perform> a gymnastics routine on the bars',
    '<do> squats with a barbell',
    '<lift> weights',
    '<do> bench presses',
    '<do> lunges',
    '<do> burpees',
    '<stretch> {pos} legs on the floor',
    '<touch> {pos} toes',
    '<hold> a plank',
    '<ride> a horse',
    '<ride> a scooter',
    '<fly|flies|flying> a plane',
    '<skate> on a skateboard',
    '<roller-skate> around a rink',
    '<ski> down a mountain',
    '<snowboard> down a slope',
    '<play> the piano',
    '<play> the flute',
    '<play> the cello',
    '<beat> a drum',
    '<conduct> an orchestra',
    '<sing> into a microphone',
    '<play> volleyball',
    '<play> golf',
    '<catch> a ball',
    '<throw> a football',
    '<swing> a golf club',
    '<spike> a volleyball',
    '<bowl> a cricket ball',
    '<throw> a javelin',
    '<throw> a discus',
    '<put> the shot',
    '<shoot> a gun',
    '<aim> a rifle',
    '<fence> with a foil',
    '<wrestle> an opponent',
    '<carry> a box',
    '<carry> a child on {pos} back',
    '<push> a heavy cart',
    '<pull> a rope',
    '<drag> a heavy bag',
    '<push> a lawnmower',
    '<dig> a hole with a shovel',
    '<chop> wood with an axe',
    '<hammer> a nail',
    '<saw> a plank of wood',
    '<drill> a hole in the wall',
    '<rake> leaves',
    '<water> the plants',
    '<plant> seeds in the garden',
    '<cook> dinner',
    '<bake> a cake',
    '<wash> {pos} hands',
    '<brush> {pos} hair',
    '<shave> {pos} face',
    '<put> on a jacket',
    '<take> off {pos} shoes',
    '<tie> {pos} tie',
    '<button> {pos} shirt',
    '<wash> a car',
    '<clean> the windows',
    '<dust> the shelves',
    '<iron> a shirt',
    '<fold> laundry',
    '<make> the bed',
    '<drink> a glass of water',
    '<eat> an apple',
    '<eat> soup with a spoon',
    '<eat> with chopsticks',
    '<cut> a steak',
    '<sip> tea',
    '<read> a newspaper',
    '<write> on a blackboard',
    '<text> on a phone',
    '<answer> the phone',
    '<open> a window',
    '<close> a door',
    '<knock> on a door',
    '<turn> a doorknob',
    '<draw> a picture',
    '<paint> on a canvas',
    '<knit> a scarf',
    '<play> cards',
    '<play> chess',
    '<play> a video game',
    '<throw> a dart',
    '<shuffle> a deck of cards',
    '<do> a magic trick',
    '<ride> a unicycle',
    '<walk> a tightrope',
    '<pet> a dog',
    '<feed> the ducks',
    '<milk> a cow',
    '<hug> someone',
    '<kiss> someone',
    '<shake> hands with someone',
    '<hold> hands with a partner',
    '<high-five> a friend',
    '<help> someone up',
    '<carry> groceries',
    '<push> a stroller',
    '<put> on makeup',
    '<take> a selfie',
    '<look> through binoculars',
    '<pray> with {pos} hands together',
    '<meditate>',
    '<sleep|sleeps|sleeping> in bed',
    '<nap> on the couch',
    '<sneeze>',
    '<cough>',
    '<laugh> out loud',
    '<cry|cries|crying>',
    '<scream>',
    '<whistle>',
    '<snap> {pos} fingers',
    '<shrug>',
    '<shake> {pos} head',
    '<scratch> {pos} head',
    '<rub> {pos} eyes',
    '<check> {pos} watch',
    '<hop> like a rabbit',
    '<slither> like a snake',
    '<swing> from a vine like a monkey',
    '<bark> like a dog',
    '<pretend> to be an airplane',
    '<rappel> down a cliff',
    '<parachute> from a plane',
    '<bungee jump>',
    '<pole-vault>',
    '<do> a breakdance headspin',
    '<do> a pirouette',
    '<bounce> a ball',
    '<lay> bricks',
    '<fix> a car engine',
    '<spray> paint on a wall',
    '<hang> from a bar',
    '<swing> on a swing',
    '<slide> down a slide',
    '<play> hopscotch',
    '<fly|flies|flying> a kite',
    '<throw> snowballs',
    '<build> a sandcastle',
)


def foreign_lexicon(lexicon: str = "bandai"):
    """The corpus lexicon with :data:`FOREIGN_PHRASES` as its only content (``foreign``), the styles kept."""
    import dataclasses

    from ..data.lexicon import Words, load_lexicon

    lex = load_lexicon(lexicon)
    return dataclasses.replace(lex, contents={"foreign": Words(FOREIGN_PHRASES)})


def foreign_captions(per_phrase: int = 24, seed: int = 0, lexicon: str = "bandai") -> list[str]:
    """``per_phrase`` distinct captions per foreign phrasing, in the training captions' grammar and styles
    (training words only), deterministic for ``seed``."""
    import dataclasses

    from ..data.augment import augment_caption
    from ..data.captions import NOISE, STRUCTURES, _fill, structures_for
    from ..data.lexicon import Words

    lex = foreign_lexicon(lexicon)
    styles = sorted(lex.styles)
    out: list[str] = []
    for phrase in FOREIGN_PHRASES:
        one = dataclasses.replace(lex, contents={"foreign": Words((phrase,))})
        rng = random.Random(zlib.crc32(f"{seed}|{phrase}".encode()))
        seen: set[str] = set()
        for _ in range(20 * per_phrase):
            if len(seen) == per_phrase:
                break
            style = rng.choice(styles)
            form = rng.choice(structures_for(one, style))
            text = augment_caption(_fill(STRUCTURES[form], one, "foreign", style, rng, False), rng, None, NOISE)
            if text.lower() not in seen:
                seen.add(text.lower())
                out.append(text)
    return out


__all__ = ["FOREIGN_PHRASES", "foreign_captions", "foreign_lexicon"]
